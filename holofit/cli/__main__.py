"""``python -m holofit.cli``: the ``holofit`` command."""

from holofit.cli import main

main(prog_name="holofit")
