"""Every registered plugin against its kind's contract (fusionkit.testing)."""

import numpy as np
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


# -- a new user's probe (stop 33): plainly broken plugins passed the contract


def test_contract_refuses_a_plugin_that_does_not_subclass_its_kinds_protocol():
    """A ``Plugin`` subclass saying ``kind = "filter"`` with no ``run()`` passed check_plugin, and register()
    and make() took it (``.run()`` then raised AttributeError); so did a Filter not implementing run()."""
    from fusionkit.errors import PluginError
    from fusionkit.filters.poisson import PoissonFilter
    from fusionkit.protocols import Filter, Plugin
    from fusionkit.registry import Registry

    class NotAFilter(Plugin):
        name = "test-not-a-filter"
        kind = "filter"

    class NoRun(Filter):
        name = "test-no-run"
        reset = PoissonFilter.reset
        update = PoissonFilter.update

    for cls, why in ((NotAFilter, r"NotAFilter says kind='filter' but does not subclass fusionkit.protocols.Filter"),
                     (NoRun, r"NoRun does not implement run\(\)")):
        with pytest.raises(AssertionError, match=why):
            check_plugin(cls)
        with pytest.raises(PluginError, match=why):
            Registry(use_entry_points=False).register(cls)


def test_contract_catches_an_estimator_drifting_off_unit_norm():
    """Only the state's initial round trip was checked: an estimator whose quaternion grew 0.1% a step passed."""
    from fusionkit.protocols import Estimator
    from fusionkit.rotations import quat_from_rotvec, quat_mul

    class Drifts(Estimator):  # (the probe's: a quaternion it never normalises, scaled on every step)
        name = "test-drifts"

        def initial_state(self, quat):
            return np.array(quat, dtype=float)

        def propagate(self, state, gyr, dt):
            state[:] = quat_mul(state, quat_from_rotvec(gyr * dt)) * 1.001

        def quat(self, state):
            return state.copy()

    with pytest.raises(AssertionError, match=r"test-drifts: quat\(\) is off unit norm by 1.00e-03 after 1 steps"):
        check_plugin(Drifts)


def _edits(sample):
    a = sample.acc if sample.acc is not None else sample.gyr
    a *= 1.001  # in place: the probe's "a = sample.acc; a *= 1.001"


def test_contract_catches_a_plugin_that_changes_its_input(monkeypatch):
    """A plugin editing its input sample in place (which changed the user's recording) passed the contract;
    each kind is now checked for it (sensor models and detectors called directly, correctors in the pipeline,
    whose samples are read-only, estimators on their rate)."""
    from fusionkit import registry, sim
    from fusionkit.estimators.poisson import PoissonQuat
    from fusionkit.protocols import Correction, Corrector, Detector, SensorModel

    class Model(SensorModel):
        name = "test-edits-model"

        def apply(self, state, sample, quat):
            _edits(sample)
            return sample, 0

    class Cor(Corrector):
        name = "test-edits-cor"
        mode = "rate"

        def correct(self, estimator, est_state, state, sample, flags):
            _edits(sample)
            return Correction(None, 0)

    class Det(Detector):
        name = "test-edits-det"
        flag = fk.Flag.MOTION

        def initial_state(self, dt):
            return np.zeros(0)

        def step(self, state, sample):
            _edits(sample)
            return 0

    class Est(PoissonQuat):
        name = "test-edits-est"

        def propagate(self, state, gyr, dt):
            gyr *= 0.5
            super().propagate(state, gyr, dt)

        def kernel(self):
            return None

    reg = registry.Registry()
    monkeypatch.setattr(registry, "_DEFAULT", reg)  # (registered for this test alone)
    rec = sim.simulate([sim.Rest(1.2), sim.Rotate((0, 0, 1), 0.5, 0.3)], rate=100.0, gnss_rate=None)
    acc = rec.acc.copy()
    for cls, why in ((Model, r"test-edits-model: apply\(\) changed sample.acc in place"),
                     (Cor, r"test-edits-cor: it changes the sample it is given: corrector 'test-edits-cor' wrote into"),
                     (Det, r"test-edits-det: it changes the sample it is given: detector 'test-edits-det' wrote into"),
                     (Est, r"test-edits-est: propagate\(\) changed the rate it was given in place")):
        reg.register(cls)
        with pytest.raises(AssertionError, match=why):
            check_plugin(cls, rec=rec)
        assert np.array_equal(rec.acc, acc)
