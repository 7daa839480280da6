"""Figure files of analysis.diagnose: the effect ranking and the chi2/dof staircase, drawn by
:mod:`analysis.plotting.compare_plots`."""
from __future__ import annotations

from pathlib import Path

from analysis.plotting.compare_plots import (plot_chi2_staircase, plot_effect_ranking,
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


def write_loop_figures(staircase, first_diagnosis, folder, dataset) -> list:
    """The loop's figures into ``folder``: staircase.png (every stage's chi2/dof) and, when a
    diagnosis ran, ranking.png (its first step's ranking).

    Parameters
    ----------
    staircase : DataFrame - stage, chi2_dof (``LoopResult.staircase``)
    first_diagnosis : analysis.diagnose.Diagnosis or None
    folder : path of an existing folder
    dataset : analysis.measurements.Dataset - names the ranking, marks a synthetic dataset

    Returns
    -------
    list of str - the names of the files written
    """
    plt = pyplot()
    folder = Path(folder)
    fig, ax = plt.subplots(figsize=(5.5, 3.5))
    plot_chi2_staircase(staircase, ax=ax, synthetic=bool(getattr(dataset, "synthetic", False)))
    fig.tight_layout()
    save_png(fig, folder / "staircase.png", 120)
    names = ["staircase.png"]
    if first_diagnosis is not None:
        fig, ax = plt.subplots(figsize=ranking_figsize(first_diagnosis))
        plot_effect_ranking(first_diagnosis, ax=ax, dataset=dataset)
        fig.tight_layout()
        save_png(fig, folder / "ranking.png", 120)
        names.append("ranking.png")
    return names
