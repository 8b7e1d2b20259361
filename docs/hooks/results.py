"""mkdocs hook: fill the ``<!-- results:table NAME -->`` markers of a page with tables built from
``benchmarks/results/*.json`` (:mod:`benchmarks.results_tables` does the work; this is the glue)."""

from __future__ import annotations

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks import results_tables


def on_config(config):
    """``mkdocs serve`` rebuilds when a results file or the table code changes."""
    for path in (results_tables.RESULTS_DIR, Path(results_tables.__file__)):
        if str(path) not in config["watch"]:
            config["watch"].append(str(path))
    return config


def on_page_markdown(markdown, page, config, files):
    if not results_tables.MARKER.search(markdown):
        return markdown
    try:
        return results_tables.fill(markdown)
    except (FileNotFoundError, ValueError, KeyError) as error:
        from mkdocs.exceptions import PluginError

        raise PluginError(f"{page.file.src_uri}: cannot build its results tables: {error!r}") from error
