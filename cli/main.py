"""The ``rgb2cloud`` command line: stream, train, evaluate, export, fit, baselines, calibrate, client.

Each command lives in the module of its group (``cli/fit.py``, ``cli/train.py``, ...), parses its
options, calls one function of the trainer or the client, and prints. Heavy imports happen inside
each command, so ``rgb2cloud --help`` is instant and ``rgb2cloud client`` and ``stream`` work in the
torch-free serving install.
"""

from __future__ import annotations

import typer

from cli.client import client
from cli.evaluate import baselines, calibrate, evaluate
from cli.fit import fit
from cli.stream import stream
from cli.train import export, train

app = typer.Typer(help="rgb2cloud: metric depth and point clouds from one RGB image.", no_args_is_help=True)
for command in (stream, train, evaluate, export, fit, baselines, calibrate, client):
    app.command()(command)


def run_app(commands: typer.Typer) -> None:
    """Run a command line; mistakes a user can fix print one line and exit 1, a bug keeps its traceback.

    A user's mistake is a ``UserError`` (a bad config, recording, card or option), a ``ValidationError``
    (options or files that do not fit their schema) or an ``OSError`` (a path that is missing or
    unreadable); anything else propagates, so its traceback says where the bug is.
    """
    from pydantic import ValidationError

    from contract.errors import UserError

    try:
        commands()
    except (OSError, UserError, ValidationError) as e:
        typer.echo(f"error: {e}", err=True)
        raise SystemExit(1) from None


def main() -> None:
    run_app(app)
