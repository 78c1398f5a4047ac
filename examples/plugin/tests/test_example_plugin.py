"""The plugin author's whole test suite: one contract check per plugin."""

from fusionkit.testing import check_plugin


def test_tilt_corrector_contract():
    check_plugin("example-tilt")


def test_complementary_filter_contract():
    check_plugin("example-complementary")
