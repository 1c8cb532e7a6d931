"""Print benchmark rows as a table: figure, value, target, pass/fail."""

from __future__ import annotations


def print_table(title: str, rows: list[tuple[str, str, str, bool]]) -> bool:
    """rows: (figure, value, target, passed). Returns True when every row passed."""
    widths = [max(len(r[i]) for r in rows + [("figure", "value", "target", True)]) for i in range(3)]
    print(f"\n{title}")
    head = f"{'figure':<{widths[0]}}  {'value':>{widths[1]}}  {'target':<{widths[2]}}  result"
    print(head)
    print("-" * len(head))
    for fig, val, tgt, ok in rows:
        print(f"{fig:<{widths[0]}}  {val:>{widths[1]}}  {tgt:<{widths[2]}}  {'pass' if ok else 'FAIL'}")
    return all(r[3] for r in rows)
