"""What the command-line tests share (the ``cli`` fixture itself is in conftest.py)."""

from click.testing import CliRunner


def invoke(cli, args, input=None):
    """``cli`` run with ``args`` (and ``input`` on stdin) in-process; an exception it raises is raised here."""
    return CliRunner().invoke(cli, args, input=input, catch_exceptions=False)
