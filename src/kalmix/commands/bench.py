"""``kalmix bench``: speed and memory against filterpy and simdkalman (see :mod:`kalmix.benchmarking`)."""

from __future__ import annotations

import click

from ._common import figure_file, one_line_errors, output_file


@click.command()
@click.option("--quick", is_flag=True, help="Small sizes: the whole run takes under a minute.")
@click.option("--json", "json_path", type=click.Path(dir_okay=False), callback=output_file,
              help="Write every figure as JSON.")
@click.option("--png", "png_path", type=click.Path(dir_okay=False), callback=figure_file,
              help="Write the scaling curves as PNG.")
@one_line_errors
def bench(quick: bool, json_path: str | None, png_path: str | None):
    """Measure (a) one stream K=40 vs filterpy IMM, (b) N targets x 40, (c) plain KF vs simdkalman, (d) scaling."""
    from ..benchmarking import main

    main(quick=quick, json_path=json_path, png_path=png_path, log=click.echo)
