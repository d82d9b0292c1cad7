"""The rate benchmarks' scores of a discovery against the injected term, on hand-written
``terms`` lists whose answers are known by reading them."""

from bikeid.experiments.measured.discovery_scores import score_discovery


def _t(eq, term, c, lo, hi, alike=()):
    return {"equation": eq, "term": term, "coefficient": c, "interval": [lo, hi],
            "indistinguishable": list(alike)}  # fmt: skip


def test_term_kept_alone_within_and_covering():
    """-3.5 for -3 is 17 % off (within 35 %), its interval -4..-3.2 misses -3."""
    s = score_discovery([_t("roll", "phidot", -3.5, -4.0, -3.2)], "roll: phidot", -3.0)
    assert s["found"] and s["direct"] and s["within35"] and not s["covers"]
    assert s["estimate"] == -3.5 and not s["wrong"]


def test_term_in_the_set_counts_found_but_not_direct_and_extras_break_found():
    """The injected term in the kept term's set is found (not direct); with a second kept
    term it is not found, though its coefficient (-1.5 for -3: 50 % off) is still scored."""
    member = _t("roll", "phidot", -1.5, -2.5, -0.5)
    kept = [_t("roll", "v*phidot", -1.0, -1.2, -0.8, [member])]
    s = score_discovery(kept, "roll: phidot", -3.0)
    assert s["found"] and not s["direct"] and not s["within35"] and not s["covers"]
    s2 = score_discovery([*kept, _t("steer", "delta", 0.1, 0.05, 0.15)], "roll:phidot", -3.0)
    assert not s2["found"] and s2["wrong"] and s2["estimate"] == -1.5


def test_no_effect_and_a_wrong_term():
    """Nothing injected: anything kept is a false discovery; a wrong term alone is not
    found and is wrong."""
    assert score_discovery([], None)["false_discovery"] is False
    assert score_discovery([_t("steer", "T", -0.02, -0.03, -0.01)], None)["false_discovery"]
    s = score_discovery([_t("steer", "v*phi", 1.0, 0.5, 1.5)], "roll: phi", -30.0)
    assert not s["found"] and s["wrong"] and s["estimate"] is None
