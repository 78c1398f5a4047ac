"""Every registered plugin against its kind's contract (fusionkit.testing)."""

import pytest

import fusionkit as fk
from fusionkit.pipeline import Pipeline
from fusionkit.testing import check_plugin

ALL = [(k[:-1], n) for k, names in fk.available().items() for n in names if n != "pipeline"]


def _composed_by_a_preset():
    """(kind, name) -> the pipeline config of the first registered preset (a ``Pipeline`` filter,
    default parameters) that composes that corrector or sensor model. Each pipeline composition is
    a compile of its own (README, "Run the tests"): a corrector or model checked in a preset's
    composition, which the preset's own contract check compiles, costs no compile of its own; the
    others are checked in the smallest pipeline they run in."""
    found = {}
    for name in fk.available()["filters"]:
        cls = fk.get(name, "filter")
        if name == "pipeline" or not issubclass(cls, Pipeline):
            continue
        cfg = cls().pipeline_config()
        for kind, entries in (("corrector", cfg.correctors), ("model", cfg.models)):
            for e in entries:
                found.setdefault((kind, e.name), cfg)
    return found


WITHIN = _composed_by_a_preset()


@pytest.mark.parametrize("kind,name", ALL)
def test_plugin_contract(kind, name):
    check_plugin(fk.get(name, kind), within=WITHIN.get((kind, name)))


def test_contract_checks_a_plugin_in_its_preset(monkeypatch):
    """``within``: the corrector runs in the preset's pipeline, with the parameters it is checked with."""
    from fusionkit import testing

    seen = []
    monkeypatch.setattr(testing, "_check_corrector_in", lambda cls, p, rec: seen.append(p))
    check_plugin("inertial-tilt", params={"tau": 7.0}, within=WITHIN[("corrector", "inertial-tilt")])
    (p,) = seen
    assert [c.name for c in p.correctors] == [c.name for c in fk.make("recommended").correctors]
    (tilt,) = [c for c in p.correctors if c.name == "inertial-tilt"]
    assert tilt.config.tau == 7.0
    with pytest.raises(AssertionError, match="has 0 correctors of that name"):
        check_plugin("dcm-field", within=WITHIN[("corrector", "inertial-tilt")])


def test_pipeline_contract():
    check_plugin(Pipeline, params={"estimator": "poisson-dcm", "alignment": {"mode": "fixed", "duration": 1.0}})


def test_contract_catches_a_broken_filter():
    from fusionkit.filters.poisson import PoissonFilter

    class Broken(PoissonFilter):
        name = "broken"

        def update(self, gyr, acc, mag=None, dt=None):
            return super().update(gyr, acc, mag, dt) * -1.0 + 1e-3  # not what run() gives

    with pytest.raises(AssertionError, match="run\\(\\) and a loop of update\\(\\) differ"):
        check_plugin(Broken)
