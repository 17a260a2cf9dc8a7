"""Every stage has a subcommand with --help."""

import pytest
from click.testing import CliRunner

from holofit.cli import main


@pytest.mark.parametrize(
    "stage", ["crop", "prefit", "library", "fit", "analyze", "simulate", "demo"]
)
def test_help(stage):
    res = CliRunner().invoke(main, [stage, "--help"])
    assert res.exit_code == 0 and "Usage" in res.output
