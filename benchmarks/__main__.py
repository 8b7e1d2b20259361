"""``python -m benchmarks [--quick] [--json FILE] [--png FILE]``: see :mod:`kalmix.benchmarking`."""

import argparse

from kalmix.benchmarking import main

parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
parser.add_argument("--quick", action="store_true", help="small sizes, under a minute")
parser.add_argument("--json", dest="json_path", metavar="FILE", help="write all figures as JSON")
parser.add_argument("--png", dest="png_path", metavar="FILE", help="write the scaling curves as PNG")
arguments = parser.parse_args()
main(quick=arguments.quick, json_path=arguments.json_path, png_path=arguments.png_path)
