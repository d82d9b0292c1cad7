"""The one unit table and its parser (``dataset.units``): values with units to SI, case.

Independent source: the factors below are typed in from the definitions (NIST SP 811,
appendix B; ISO 80000-3): 1 km/h = 1/3.6 m/s, 1 mph = 1609.344 m / 3600 s = 0.44704 m/s,
1 deg = pi/180 rad, 1 ms = 0.001 s, 1 N cm = 0.01 N m.  A conversion is one multiplication,
so a round trip agrees to 1 ulp-ish (rel 1e-15).
"""

from __future__ import annotations

import math

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.dataset.units import CONVERSIONS, parse_quantity, resolve_unit, si_reading
from bikeid.sim.conventions import UNITS

# (unit, SI unit, factor from the definition)
HAND = [
    ("m/s", "m/s", 1.0), ("km/h", "m/s", 1 / 3.6), ("kph", "m/s", 1 / 3.6),
    ("mph", "m/s", 1609.344 / 3600), ("deg", "rad", math.pi / 180), ("rad", "rad", 1.0),
    ("deg/s", "rad/s", math.pi / 180), ("rad/s", "rad/s", 1.0), ("ms", "s", 0.001),
    ("s", "s", 1.0), ("N cm", "N m", 0.01), ("N m", "N m", 1.0),
]  # fmt: skip


def test_the_table_holds_every_si_unit_and_the_hand_factors():
    assert set(UNITS.values()) | {"s"} <= set(CONVERSIONS)
    for unit, si, f in HAND:
        assert CONVERSIONS[si][unit] == pytest.approx(f, rel=1e-15), unit
    assert {u for si in CONVERSIONS for u in CONVERSIONS[si]} == {u for u, _, _ in HAND} | {
        "N", "m"}


@settings(max_examples=200, deadline=None)
@given(value=st.floats(min_value=-1e6, max_value=1e6, allow_nan=False),
       case=st.sampled_from(HAND), blank=st.sampled_from(["", " ", "  "]))
def test_value_with_unit_to_si_round_trip(value, case, blank):
    unit, si, f = case
    got = parse_quantity(f"{value!r}{blank}{unit}", si)
    assert got == pytest.approx(value * f, rel=1e-15, abs=1e-300)
    assert parse_quantity(repr(value), si) == value  # a bare number is in SI


@settings(max_examples=300, deadline=None)
@given(case=st.sampled_from(HAND), mask=st.lists(st.booleans(), min_size=8, max_size=8))
def test_a_case_variant_is_the_same_unit_or_refused_never_another_value(case, mask):
    """Any upper/lower-case spelling of a table unit either converts exactly as the unit
    does, or is refused naming the unit meant; it never gives another number."""
    unit, si, f = case
    text = "".join(c.upper() if m else c.lower() for c, m in zip(unit, mask * 2, strict=False))
    try:
        got = parse_quantity(f"2{text}", si)
    except ValueError as exc:
        assert "ambiguous" in str(exc) and repr(unit) in str(exc), str(exc)
        assert si_reading(text) is not None  # refused only when SI reads it as another unit
        return
    assert got == pytest.approx(2 * f, rel=1e-15)


@pytest.mark.parametrize(("text", "si", "name"), [
    ("KM/H", "m/s", "km/h"), ("Km/h", "m/s", "km/h"), ("M/S", "m/s", "m/s"),
    ("MPH", "m/s", "mph"), ("Deg", "rad", "deg"), ("DEG/S", "rad/s", "deg/s"),
    ("RAD/S", "rad/s", "rad/s"), ("n CM", "N m", "N cm"), (" km / h ", "m/s", "km/h"),
    ("N*m", "N m", "N m"),
])  # fmt: skip
def test_unambiguous_case_variants_are_accepted(text, si, name):
    assert resolve_unit(text, si) == name


@pytest.mark.parametrize(("text", "si", "meant", "reading"), [
    ("Ms", "s", "ms", "megasecond"), ("mS", "s", "ms", "millisiemens"),
    ("MS", "s", "ms", "megasiemens"), ("S", "s", "s", "siemens"),
    ("m/S", "m/s", "m/s", "metre per siemens"), ("km/H", "m/s", "km/h", "kilometre per henry"),
    ("rad/S", "rad/s", "rad/s", "radian per siemens"),
])  # fmt: skip
def test_case_variants_with_another_si_meaning_are_refused_with_the_candidate(
    text, si, meant, reading
):
    with pytest.raises(ValueError) as e:
        resolve_unit(text, si, "'t'")
    msg = str(e.value)
    assert "ambiguous" in msg and reading in msg and f"write {meant!r}" in msg, msg
    for u in CONVERSIONS[si]:
        assert repr(u) in msg  # the candidates listed


def test_a_unit_of_another_quantity_is_named_as_such():
    with pytest.raises(ValueError, match=r"'deg' for --speed is a unit of an angle; --speed "
                                         r"is a speed; allowed: \['m/s', 'km/h'"):
        parse_quantity("5deg", "m/s", "--speed")
    with pytest.raises(ValueError, match="not a number with an optional unit"):
        parse_quantity("fast", "m/s", "--speed")
    with pytest.raises(ValueError, match="not a number"):
        parse_quantity("nan", "m/s")


def test_one_table_and_one_parser_behind_every_speed_option():
    """The importers' table is the units table, and identify's --speed is the args type."""
    from bikeid.dataset import importers
    from bikeid.experiments.cli import args, log_options

    assert importers.CONVERSIONS is CONVERSIONS
    assert log_options.speed_arg is args.positive_speed
    for parse in (args.speed_value, args.positive_speed):
        assert parse("14.4KM/H") == pytest.approx(4.0, rel=1e-15)
        assert parse("9 mph") == pytest.approx(9 * 0.44704, rel=1e-15)
