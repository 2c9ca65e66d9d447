"""Names made safe for writers: control characters refused, Markdown/HTML inert, formulas neutralised."""

import pytest
from hypothesis import given, strategies as st

from hybridfit import text
from hybridfit.errors import HybridfitError


@given(st.text())
def test_markdown_cells_hold_no_tag_no_link_no_row_break(name):
    out = text.markdown(name)
    assert "<" not in out and ">" not in out and "\n" not in out and "\r" not in out
    assert "|" not in out.replace("\\|", "")
    assert "](" not in out.replace("\\](", "")


@given(st.text())
def test_csv_cells_never_start_a_formula(name):
    out = text.csv_cell(name)
    try:
        float(out)
        return  # a plain number, kept as written
    except ValueError:
        pass
    assert not out or out[0] not in "=+-@\t\r"


@pytest.mark.parametrize("name", ["a\x00b", "a\nb", "a\tb", "\x1b[31mred", "a\u202eb"])
def test_control_characters_are_refused_naming_where(name):
    with pytest.raises(HybridfitError, match="f.npz: joint_names"):
        text.check_name(name, "f.npz: joint_names")


def test_printable_names_pass_and_dollars_are_literal_for_matplotlib():
    assert text.check_name("index_proximal", "x") == "index_proximal"
    assert text.plain("cost_$5_vs_$10") == r"cost_\$5_vs_\$10"
    assert text.plain("f\udcff.npz", "ascii") == "f\\udcff.npz"
