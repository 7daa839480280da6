"""Figure files of analysis.diagnose: the effect ranking and the chi2/dof staircase, drawn by
:mod:`analysis.plotting.compare_plots`."""
from __future__ import annotations

from pathlib import Path

from analysis.plotting.compare_plots import (loop_staircase_figsize, plot_chi2_staircase,
                                             plot_effect_ranking, plot_loop_staircase,
                                             ranking_figsize)
from analysis.plotting.files import pyplot, save_png


def write_diagnosis_figures(diagnosis, folder, staircase=None, *, dataset_name: str = "",
                            synthetic: bool = False) -> list:
    """ranking.png (:func:`plot_effect_ranking`) and, with ``staircase``, staircase.png
    (:func:`plot_chi2_staircase`) into ``folder``.

    Parameters
    ----------
    diagnosis : analysis.diagnose.Diagnosis
    folder : path of an existing folder
    staircase : DataFrame or None - stage, chi2_dof (``AddEffectResult.staircase``)
    dataset_name : str - the ranking's title
    synthetic : bool - the dataset is synthetic: SYNTHETIC mark on both figures

    Returns
    -------
    list of str - the names of the files written
    """
    plt = pyplot()
    folder = Path(folder)
    fig, ax = plt.subplots(figsize=ranking_figsize(diagnosis))
    plot_effect_ranking(diagnosis, ax=ax, dataset_name=dataset_name, synthetic=synthetic)
    fig.tight_layout()
    save_png(fig, folder / "ranking.png", 120)
    names = ["ranking.png"]
    if staircase is not None:
        fig, ax = plt.subplots(figsize=(5, 3.5))
        plot_chi2_staircase(staircase, ax=ax, synthetic=synthetic)
        fig.tight_layout()
        save_png(fig, folder / "staircase.png", 120)
        names.append("staircase.png")
    return names


def write_loop_figures(staircase, first_diagnosis, folder, dataset, *, fake: bool = False,
                       quoted=None, threshold_scale: float = 1.0) -> list:
    """The loop's figures into ``folder``: staircase.png (every stage's chi2/dof,
    :func:`plot_loop_staircase`) and, when a diagnosis ran, ranking.png (its first step's
    ranking with the threshold that step applied, :func:`plot_effect_ranking`).

    Parameters
    ----------
    staircase : DataFrame - stage, chi2, dof, chi2_dof (``LoopResult.staircase``)
    first_diagnosis : analysis.diagnose.Diagnosis or None
    folder : path of an existing folder
    dataset : analysis.measurements.Dataset - names the ranking, marks a synthetic dataset
    fake : the loop ran on the FAKE twin: FAKE in both titles, a watermark and the PNG's
        Title / Description text chunks
    quoted : {role: row} of the staircase rows the verdict quotes (default
        :func:`analysis.report.loop_words.quoted_stages`)
    threshold_scale : the bootstrap's scale of the first step's threshold

    Returns
    -------
    list of str - the names of the files written
    """
    from analysis.report.loop_words import FAKE_WORDS
    plt = pyplot()
    folder = Path(folder)
    synth = bool(getattr(dataset, "synthetic", False))
    name = getattr(dataset, "name", "") or ""
    fig, ax = plt.subplots(figsize=loop_staircase_figsize(staircase))
    plot_loop_staircase(staircase, ax=ax, quoted=quoted, synthetic=synth, fake=fake,
                        title="chi2/dof staircase of the loop on %s" % name if name else None)
    fig.tight_layout()
    meta = {"Title": ax.get_title()}
    if fake:
        meta["Description"] = FAKE_WORDS
    save_png(fig, folder / "staircase.png", 120, meta)
    names = ["staircase.png"]
    if first_diagnosis is not None:
        fig, ax = plt.subplots(figsize=ranking_figsize(first_diagnosis))
        plot_effect_ranking(first_diagnosis, ax=ax, dataset=dataset, fake=fake, step=1,
                            threshold_scale=threshold_scale)
        fig.tight_layout()
        meta = {"Title": ax.get_title()}
        if fake:
            meta["Description"] = FAKE_WORDS
        save_png(fig, folder / "ranking.png", 120, meta)
        names.append("ranking.png")
    return names
