"""The ``kalmix`` command line: a thin layer over experiments and predictors.

Each sub-command lives in :mod:`kalmix.commands` (one module each) and is registered
here; the heavy imports happen inside the commands, so ``kalmix --help`` is fast.
"""

from __future__ import annotations

import importlib
import sys

COMMANDS = {
    # name: (module, attribute)
    "demo": ("kalmix.commands.demo", "demo"),
    "reproduce": ("kalmix.commands.reproduce", "reproduce"),
    "servo": ("kalmix.commands.servo", "servo"),
    "predict": ("kalmix.commands.predict", "predict"),
    "evaluate": ("kalmix.commands.predict", "evaluate"),
    "bench": ("kalmix.commands.bench", "bench"),
}


def _missing_cli_extra(error: ImportError) -> None:
    sys.stderr.write(f"kalmix: the command line needs the 'cli' extra ({error.name} is missing): "
                     "pip install 'kalmix[cli]'\n")
    raise SystemExit(2)


def build():
    """The click group with every sub-command whose module is present."""
    try:
        import click
    except ImportError as error:  # pragma: no cover - depends on the environment
        _missing_cli_extra(error)

    @click.group(context_settings={"help_option_names": ["-h", "--help"]})
    @click.version_option(package_name="kalmix")
    def group():
        """kalmix: model-free online motion prediction with a mixture of adaptive Kalman filters."""

    for name, (module_name, attribute) in COMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as error:
            if error.name == module_name:
                continue  # command not shipped in this build
            raise
        group.add_command(getattr(module, attribute), name)
    return group


def main(argv=None):
    """Entry point of the ``kalmix`` script."""
    try:
        return build()(args=argv, prog_name="kalmix")
    except ImportError as error:
        _missing_cli_extra(error)


if __name__ == "__main__":  # pragma: no cover
    main()
