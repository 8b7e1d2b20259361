"""mkdocs hook: the command-line page shows no default where an option has none.

click (8.2 and later) marks an option without a default with a sentinel, which mkdocs-click writes
into the Default column as ``Sentinel.UNSET``; ``kalmix <command> --help`` shows nothing there.
mkdocs-click expands its blocks while the markdown is converted, so this edits the page's HTML.
"""

import re

_UNSET = re.compile(r"<code>Sentinel\.UNSET</code>")


def on_page_content(html, page, config, files):
    if page.file.src_uri != "cli.md":
        return html
    return _UNSET.sub("", html)
