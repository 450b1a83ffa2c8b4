"""Report formatting (``lnn_torch.evaluation.report``): the one place for the cells and Markdown tables the
evaluation report, the stability tables, ``lnn-torch identify`` and the benchmarks write."""

import math

from lnn_torch.evaluation.report import (
    markdown_table,
    number,
    pct,
    quartile_cell,
    scalar_rows,
    table_header,
    table_row,
    time_cell,
)


def test_cells():
    assert pct(0.0007) == "0.07 %" and pct(1.234567) == "123 %" and pct(0.01234, 2) == "1.2 %"
    assert pct(0.0123, signed=True) == "+1.23 %" and pct(-0.0123, signed=True) == "-1.23 %"
    assert pct(math.nan) == "n/a" and number(math.nan) == "n/a"
    assert number(1.23456789) == "1.235" and number(-math.inf) == "-inf" and number(2.5e-7, ".2e") == "2.50e-07"
    assert time_cell(1.234, 5.0) == "1.23" and time_cell(5.0, 5.0) == "≥ 5"
    assert quartile_cell({"median": 2.0, "q25": 1.0, "q75": 5.0}, 5.0) == "2.00 [1.00, ≥ 5]"
    assert quartile_cell({"median": 5.0, "q25": 5.0, "q75": 5.0}, 5.0) == "≥ 5 (never exceeded)"


def test_tables():
    assert table_row(["a", 1, [0.5, 1.0]]) == "| a | 1 | [0.5, 1.0] |"
    assert table_row(["", "after 0.1s"]) == "| | after 0.1s |"  # an empty cell
    assert table_header(["case", "a", "b"]) == ["| case | a | b |", "|---|---|---|"]
    assert markdown_table(["x", "y"], [["a|b", 2], ["c"]]).splitlines() == [
        "| x | y |", "|---|---|", "| a\\|b | 2 |", "| c | |"]
    assert markdown_table(["x"], [["a|b"]], escape=False).splitlines()[-1] == "| a|b |"
    assert scalar_rows({"a": 1.23456, "b": {"c": 2, "flag": True}, "_t": 3.0, "s": "text"}) == [
        "| a | 1.235 |", "| b (c) | 2 |"]
