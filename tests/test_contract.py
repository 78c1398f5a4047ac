"""Every registered plugin against its kind's contract (fusionkit.testing)."""

import pytest

import fusionkit as fk
from fusionkit.testing import check_plugin

ALL = [(k[:-1], n) for k, names in fk.available().items() for n in names if n != "pipeline"]


@pytest.mark.parametrize("kind,name", ALL)
def test_plugin_contract(kind, name):
    check_plugin(fk.get(name, kind))


def test_pipeline_contract():
    from fusionkit.pipeline import Pipeline

    check_plugin(Pipeline, params={"estimator": "poisson-dcm", "alignment": {"mode": "fixed", "duration": 1.0}})


def test_contract_catches_a_broken_filter():
    from fusionkit.filters.poisson import PoissonFilter

    class Broken(PoissonFilter):
        name = "broken"

        def update(self, gyr, acc, mag=None, dt=None):
            return super().update(gyr, acc, mag, dt) * -1.0 + 1e-3  # not what run() gives

    with pytest.raises(AssertionError, match="run\\(\\) and a loop of update\\(\\) differ"):
        check_plugin(Broken)
