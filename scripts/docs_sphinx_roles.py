"""A Griffe extension of the documentation site (mkdocs.yml): the docstrings' Sphinx roles as cross-references.

The docstrings name other objects as Sphinx does, ``:class:`PayloadRLS```, ``:func:`~eval.work.run_grid```. Markdown
would print the role. This extension rewrites each into an optional cross-reference of mkdocs-autorefs: a link where
the site documents the object, its name in code type where it does not. A relative name is looked up as Python would
from the object whose docstring holds it (its own members, then its parents' up to its module); ``~`` shows the last
component only.
"""

from __future__ import annotations

import html
import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|meth|func|mod|data|attr|exc|obj|const):`(?P<tilde>~?)(?P<name>[\w.]+)`")


def resolve(obj: griffe.Object, name: str) -> str:
    """The full path of ``name`` as written in ``obj``'s docstring; the name itself when it is absolute or unknown."""
    first, _, rest = name.partition(".")
    scope: griffe.Object | None = obj
    while scope is not None:
        member = scope.members.get(first)
        if member is not None:
            path = member.target_path if member.is_alias else member.path
            return f"{path}.{rest}" if rest else path
        scope = scope.parent
    return name


def rewrite_roles(obj: griffe.Object) -> None:
    """Replace the Sphinx roles of ``obj``'s docstring by optional cross-references."""
    if obj.docstring is None:
        return

    def reference(match: re.Match[str]) -> str:
        name = match["name"]
        shown = name.rsplit(".", 1)[-1] if match["tilde"] else name
        identifier = html.escape(resolve(obj, name), quote=True)
        return f'<autoref identifier="{identifier}" optional><code>{html.escape(shown)}</code></autoref>'

    obj.docstring.value = ROLE.sub(reference, obj.docstring.value)


class SphinxRoles(griffe.Extension):
    """Rewrites the Sphinx roles of every loaded object's docstring, a package's own included."""

    def on_object(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        rewrite_roles(obj)

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        rewrite_roles(pkg)
