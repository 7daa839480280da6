"""The two-worker run keeps a test group on one worker (tests/conftest.py): a module fixture
that a group shares - the report tests' FAKE loop, minutes of CPU - is then made once, not on
both workers at once. pytest 9.2 renamed the node id that pytest-xdist 3.8 tags with the group,
and the groups silently fell apart; requirements.txt pins a pair that keeps them."""
import pytest


@pytest.mark.xdist_group("probe")
def test_a_group_mark_tags_the_node_id_under_loadgroup(request):
    if not request.config.getoption("loadgroup", False):
        pytest.skip("not run with --dist loadgroup (make test runs it so)")
    assert request.node.nodeid.endswith("@probe"), request.node.nodeid
