"""The vibro-vs-PySINDy table the discrepancy benches print: one metric a row, both values, their ratio."""

from __future__ import annotations


def ratio(a, b):
    """a / b, or None when either is missing or b is 0."""
    return None if a is None or b is None or b == 0 else a / b


def fmt(x) -> str:
    return f"{x:.4g}" if isinstance(x, float) else str(x)


def print_side_by_side(table: dict[str, tuple]) -> None:
    """Print ``{metric: (vibro, pysindy)}`` with the PySINDy/vibro ratio where both are numbers."""
    print(f"\n{'metric':38} {'vibro':>14} {'PySINDy':>14} {'PySINDy/vibro':>14}")
    for k, (a, b) in table.items():
        q = ratio(b, a) if isinstance(a, (int, float)) and isinstance(b, (int, float)) else None
        print(f"{k:38} {fmt(a):>14} {fmt(b):>14} {('' if q is None else f'{q:.3g}'):>14}")
