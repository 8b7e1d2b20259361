"""Griffe extension: Sphinx roles in kalmix docstrings as Markdown, for mkdocstrings.

``:func:`~a.b.c``` -> ```c```, ``:class:`X``` -> ```X```, ``:math:`x``` -> ```x```:
the docstrings keep their Sphinx roles (``help()`` and IDEs show them as written) and the site
shows code spans instead of a literal ``:func:``.
"""
import re

import griffe

_ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|exc|obj|const|math):`(~?)([^`]+)`")


def _markdown(text: str) -> str:
    def one(match):
        tilde, target = match.groups()
        if tilde:
            target = target.rsplit(".", 1)[-1]
        return f"`{target}`"
    text = _ROLE.sub(one, text)
    # ``.. math:: formula`` (one line) as a code block line
    return re.sub(r"^(\s*)\.\. math::\s*(.+)$", r"\1`\2`", text, flags=re.M)


class SphinxRoles(griffe.Extension):
    def on_object(self, *, obj, **kwargs):
        if obj.docstring is not None:
            obj.docstring.value = _markdown(obj.docstring.value)
