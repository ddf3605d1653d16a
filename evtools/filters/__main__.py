"""The README's table of the filters and their parameters: ``python -m evtools.filters`` (as a module of its own,
``python -m evtools.filters.registry`` ran the registry twice, once imported by the package, and runpy warned)."""

from evtools.filters.registry import markdown_table

print(markdown_table())
