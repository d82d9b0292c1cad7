"""Figures seen, not guessed: units, layout and Bode branches (experiments.plots and the
figure writers that use it).

Independent references: analytic phases of first-order transfer functions; the importer's
own record of the user's units; sim.linear's Whipple eigenvalues for the nominal bicycle;
matplotlib's rendered text extents (Agg) for the layout.
"""

import contextlib
import io
import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bikeid.dataset.linear_loop import simulate
from bikeid.experiments import plots
from bikeid.experiments.plots import (
    angle_unit,
    display_scale,
    layout_problems,
    phase_deg,
    phases_on_one_branch,
    plt,
    points_on_branch,
)
from bikeid.sim.linear import eigenvalues, match_eigenvalues, state_space
from bikeid.sim.parameters import benchmark

P = benchmark()
W = np.logspace(-3, 2, 400)  # rad/s


def _tf(num, den, w=W):
    s = 1j * np.asarray(w)
    return np.polyval(num, s) / np.polyval(den, s)


# --- Bode phases on one branch ---------------------------------------------------------------


def test_curves_across_the_branch_cut_share_one_branch():
    """s/(s+1) starts at +89.94 deg (w = 1e-3 rad/s), inside phase_deg's (-270, 90] window;
    the same plant with a lead (1 + 2 s) starts at 90.06 deg, just outside, so phase_deg
    alone puts it 360 deg lower: drawn per curve, the two sit 360 deg apart.  On one branch,
    each equals its analytic phase 90 - atan(w) (+ atan(2 w)) [deg] to 1e-9 deg (rounding
    of np.angle), the second sampled on another grid, and they agree at the lowest
    frequency to 0.12 deg (atan(2e-3) - atan(1e-3), analytic)."""
    a = _tf([1, 0], [1, 1])
    w2 = np.logspace(-3, 2, 97)
    b = _tf([2, 1, 0], [1, 1], w2)
    naive = phase_deg(b)[0] - phase_deg(a)[0]
    assert naive == pytest.approx(-360.0, abs=0.2)  # the defect the branch fixes
    pa, pb = phases_on_one_branch([(W, a), (w2, b)])
    deg = np.degrees
    np.testing.assert_allclose(pa, 90 - deg(np.arctan(W)), atol=1e-9)
    np.testing.assert_allclose(pb, 90 - deg(np.arctan(w2)) + deg(np.arctan(2 * w2)), atol=1e-9)
    assert abs(pb[0] - pa[0]) < 0.12


@settings(max_examples=40, deadline=None)
@given(pole=st.floats(0.05, 20.0), gain=st.sampled_from([-1.0, 1.0]),
       lead=st.floats(-80.0, 80.0), turns=st.integers(-3, 3))  # fmt: skip
def test_branch_follows_the_first_curve_whatever_angle_returns(pole, gain, lead, turns):
    """Property: a second curve equal to the first times exp(j lead) (|lead| < 90 deg) is drawn
    exactly ``lead`` deg from the first (to 1e-9 deg) at every frequency, and a scattered
    point set is put within 180 deg of the curve, whatever 360-degree turn its angles come
    in with."""
    H = gain * _tf([1.0], [1.0, pole])
    rot = np.exp(1j * np.radians(lead))
    p1, p2 = phases_on_one_branch([(W, H), (W[::3], H[::3] * rot)])
    np.testing.assert_allclose(p2, p1[::3] + lead, atol=1e-9)
    pts = points_on_branch(W[::50], H[::50] * rot * np.exp(2j * np.pi * turns), W, p1)
    np.testing.assert_allclose(pts, p1[::50] + lead, atol=1e-9)


# --- units ------------------------------------------------------------------------------------

COLS = {"phi": "roll", "delta": "steer", "phidot": "roll_rate", "deltadot": "steer_rate",
        "T_delta": "torque", "v": "speed"}  # fmt: skip


def _csv(path: Path, run, degrees: bool) -> Path:
    c = np.degrees(1.0) if degrees else 1.0
    table = np.column_stack([run.t, c * run["phi"], c * run["delta"], c * run["phidot"],
                             c * run["deltadot"], run["T_delta"], run["v"]])  # fmt: skip
    with path.open("w") as fh:
        fh.write("t,roll,steer,roll_rate,steer_rate,torque,speed\n")
        np.savetxt(fh, table, delimiter=",", fmt="%.12g")
    return path


@pytest.fixture(scope="module")
def run():
    """30 s at 5 m/s under the default PID with 2 N m dither and white sensor noise."""
    return simulate(P, 5.0, duration=30, seed=3, dither=2.0, angle_noise=1e-3, rate_noise=1e-2)


DEG_UNITS = {"phi": "deg", "delta": "deg", "phidot": "deg/s", "deltadot": "deg/s"}


def test_angle_unit_is_the_users(run, tmp_path):
    """The importer's record decides: a CSV in degrees and a nested HDF5 in degrees plot in
    degrees, the same CSV in radians (no unit declared: SI) in radians; bikeid's own
    simulated run, which states nothing, in degrees (the design's convention); a model
    file's settings the same way; display_scale converts by 180/pi exactly."""
    import h5py

    from bikeid.dataset.importers import from_csv, from_hdf5

    deg = from_csv(_csv(tmp_path / "deg.csv", run, True), COLS, DEG_UNITS)
    rad = from_csv(_csv(tmp_path / "rad.csv", run, False), COLS)
    np.testing.assert_allclose(deg["phi"], rad["phi"], rtol=1e-9, atol=1e-14)  # same data
    with h5py.File(tmp_path / "nested.h5", "w") as f:
        f["clock/t"] = run.t
        for sig, col in COLS.items():
            c = np.degrees(1.0) if sig in DEG_UNITS else 1.0
            f[f"sensors/{col}"] = c * run[sig]
    h5 = from_hdf5(tmp_path / "nested.h5", {k: f"sensors/{v}" for k, v in COLS.items()},
                   DEG_UNITS, time="clock/t")  # fmt: skip
    assert (angle_unit(deg), angle_unit(h5), angle_unit(rad)) == ("deg", "deg", "rad")
    assert angle_unit(run) == "deg" and angle_unit(None) == "deg"
    assert angle_unit([rad, rad]) == "rad" and angle_unit([rad, deg]) == "deg"
    settings_ = {"format": "csv", "columns": COLS, "units": None}
    assert angle_unit(settings_) == "rad"
    assert angle_unit({**settings_, "units": {"phi": "deg"}}) == "deg"
    assert angle_unit({"format": "bikeid"}) == "deg"
    assert display_scale("phidot") == (pytest.approx(180 / np.pi, rel=1e-15), "deg/s")
    assert display_scale("phi", "rad") == (1.0, "rad")
    assert display_scale("T_delta") == (1.0, "N m")


# --- layout -----------------------------------------------------------------------------------


def test_layout_check_known_both_ways():
    """A title wider than its figure, and two side-by-side axes without a layout engine whose
    long y label runs into the left axes, are flagged; the same figures with constrained
    layout and a wrapped title are not."""
    long = "a title much wider than the figure it is drawn in, " * 3
    bad, (a, b) = plt.subplots(1, 2, figsize=(5, 3))
    a.set_title(long)
    b.set_ylabel("a long y label [units]\nin two lines")
    b.set_yticks([0, 0.5, 1], ["0.000000", "0.500000", "1.000000"])
    problems = layout_problems(bad)
    assert any("outside the figure" in p for p in problems)
    assert any("plotting area of axes 0" in p for p in problems)
    good, (a, b) = plt.subplots(1, 2, figsize=(5, 3), layout="constrained")
    a.set_title(plots.wrap_title(long, 25), fontsize=8)
    b.set_ylabel("a long y label [units]\nin two lines")
    b.set_yticks([0, 0.5, 1], ["0.000000", "0.500000", "1.000000"])
    assert layout_problems(good) == []
    plt.close("all")


@pytest.fixture()
def captured(monkeypatch):
    """Figures handed to ``save`` by the figure writers, kept open for inspection."""
    figs: dict[str, object] = {}

    def keep(fig, path):
        figs[Path(path).name] = fig
        return Path(path)

    import bikeid.experiments.measured.study_plots as sp
    import bikeid.experiments.validation_plots as vp

    for mod in (vp, sp, plots):
        monkeypatch.setattr(mod, "save", keep)
    yield figs
    plt.close("all")


def test_validation_figures_fit_in_degrees_on_one_branch(run, captured, tmp_path):
    """bikeid validate's three figures: no text outside, no overlapping labels (the old Bode
    figure had six: each column's y label over its left neighbour); angles drawn in degrees
    (the plotted measured roll equals degrees(phi) exactly) or, on request, radians; the
    model phase starts in (-270, 90] and every estimate point lies within 180 deg of the
    curve at its frequency (one branch)."""
    from bikeid.experiments.validation_plots import write_figures
    from bikeid.ident.validation_report import validate_model

    rep = validate_model(state_space(P, 5.0, inputs=("T_delta",)), run)
    write_figures(rep, tmp_path)
    assert set(captured) == {"compare_1.png", "resid.png", "bode.png"}
    for name, fig in captured.items():
        assert layout_problems(fig) == [], name
    ax = captured["compare_1.png"].axes[0]
    assert ax.get_ylabel() == "phi [deg]"
    np.testing.assert_allclose(ax.lines[0].get_ydata(), np.degrees(run["phi"]), rtol=1e-12)
    bode, n = captured["bode.png"], len(rep.frequency_responses)
    checked = 0
    for k, e in enumerate(rep.frequency_responses):
        ph_ax = bode.axes[n + k]  # row-major: magnitudes, phases, coherences
        curve = ph_ax.lines[0].get_ydata()
        assert -270 < curve[0] <= 90
        if e.valid.any():
            pts = ph_ax.containers[0].lines[0]  # the estimate's points
            f, y = pts.get_xdata(), pts.get_ydata()
            assert np.all(np.abs(y - np.interp(f, e.model_f, curve)) <= 180 + 1e-9)
            checked += 1
    assert checked >= 1
    captured.clear()
    write_figures(rep, tmp_path, angle="rad")
    assert captured["compare_1.png"].axes[0].get_ylabel() == "phi [rad]"
    # a refused simulation's reason is shown whole (it was cut at 110 characters), wrapped
    import dataclasses

    from bikeid.experiments.validation_plots import plot_compare

    note = ("simulation refused: the model is unstable (largest eigenvalue modulus 1.07) and "
            "a 30 s free-run simulation would grow by a factor 1e12; the k-step prediction "
            "and the residual tests stand, compare them instead of the simulation fit")
    series = (dataclasses.replace(rep.series[0], simulated=None),)
    plot_compare(dataclasses.replace(rep, series=series, simulation_note=note),
                 tmp_path / "c.png")  # fmt: skip
    fig = captured["c.png"]
    assert layout_problems(fig) == []
    assert note in fig.axes[0].get_title().replace("\n", " ")


def test_validation_figures_of_many_speeds_stay_readable(captured, tmp_path):
    """A validation at two speeds (a model over speed from the true matrices, 10 s runs at 4
    and 6 m/s with sensor noise): one Bode figure per speed (bode_v4.png, bode_v6.png),
    each holding the four outputs' estimates of its speed only and at most 2,000 px wide at
    save's 130 dpi (the single 116-panel figure of a 58-run sweep was 63,351 px); the resid
    figure draws one line per speed and its titles give ident.structure's verdicts, counted
    from the report's structure check; no layout problems."""
    from bikeid.experiments.validation_plots import write_figures
    from bikeid.ident.canonical import speed_params_from_matrices, theta_from_matrices
    from bikeid.ident.pem import CanonicalModel, SpeedCanonicalModel
    from bikeid.ident.validation_report import validate_model
    from bikeid.sim.linear import canonical_matrices

    speeds = (4.0, 6.0)
    runs = [simulate(P, v, duration=10, seed=1, dither=1.0, angle_noise=1e-3, rate_noise=1e-2)
            for v in speeds]  # fmt: skip
    cm, dt, outs = canonical_matrices(P), runs[0].dt, ("phi", "phidot", "delta", "deltadot")
    per = {v: CanonicalModel(theta=theta_from_matrices(cm, v), covariance=np.zeros((10, 10)),
                             K=np.zeros((4, 4)), dt=dt, speed=v, noise_covariance=np.eye(4),
                             outputs=outs) for v in speeds}  # fmt: skip
    model = SpeedCanonicalModel(params=speed_params_from_matrices(cm), per_speed=per, dt=dt,
                                covariance=np.zeros((14, 14)), g=cm.g)  # fmt: skip
    rep = validate_model(model, runs)
    write_figures(rep, tmp_path, max_runs=1)
    names = {f"bode_v{v:g}.png": v for v in speeds}
    assert set(captured) == {"compare_1.png", "resid.png", *names}
    for name, v in names.items():
        fig = captured[name]
        assert fig.get_size_inches()[0] * 130 <= 2000, name
        titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
        assert len(titles) == 4 and all(f"v = {v:g} m/s" in t for t in titles), titles
    assert layout_problems(captured["bode_v4.png"]) == []
    resid = captured["resid.png"]
    assert layout_problems(resid) == []
    assert len(resid.axes[0].lines) == len(speeds) + 1  # one per speed and the zero line
    assert "whiteness: not tested (K = 0)" in resid.axes[0].get_title().replace("\n", " ")
    bad = sum(t["rejected"] for rows in rep.structure.tests.values() for t in rows
              if t["kind"] == "independence" and t["output"] == "phi")  # fmt: skip
    word = f"rejected at {bad}" if bad else "passed at all"
    assert f"independence: {word} of 2 speeds" in resid.axes[1].get_title().replace("\n", " ")


def test_eigenvalue_plot_title_says_whether_bars_are_drawn(tmp_path, monkeypatch):
    """The complex plane's title names interval bars only when some are drawn: with every
    speed's intervals withheld (None) it says so and the plot holds no bar segments; with
    intervals at one of two speeds it names that speed, and bars are drawn (both ways,
    counted from the drawn error-bar containers)."""
    figs = {}

    def keep(fig, path):
        ax = fig.axes[0]
        segs = sum(len(lc.get_segments()) for c in ax.containers for lc in c.lines[2])
        figs["title"], figs["segments"] = ax.get_title(), segs
        plt.close(fig)
        return Path(path)

    monkeypatch.setattr(plots, "save", keep)
    ev = eigenvalues(P, 5.0)
    bounds = {"eigenvalues": [{"value": {"re": z.real, "im": z.imag},
                               "real": [z.real - 0.1, z.real + 0.1],
                               "imag": [z.imag - 0.1, z.imag + 0.1]} for z in ev]}  # fmt: skip
    bare = {"speed": 5.0, "eigenvalues": list(ev), "eigenvalue_intervals": None}
    plots.plot_identified_eigenvalues([bare], P, tmp_path / "a.png")
    assert "no 95 % intervals" in figs["title"] and "(bars)" not in figs["title"]
    assert figs["segments"] == 0
    plots.plot_identified_eigenvalues([{**bare, "eigenvalue_intervals": bounds}], P,
                                      tmp_path / "b.png")  # fmt: skip
    assert figs["title"] == "eigenvalues with 95 % intervals (bars) vs nominal (squares)"
    assert figs["segments"] >= 8  # real and imaginary bars of four eigenvalues
    plots.plot_identified_eigenvalues(
        [{**bare, "eigenvalue_intervals": bounds}, {**bare, "speed": 6.0,
         "eigenvalues": list(eigenvalues(P, 6.0))}], P, tmp_path / "c.png")  # fmt: skip
    assert "(bars) at 5 m/s only" in figs["title"]


def test_study_bode_figure_one_branch_and_degrees(captured, tmp_path):
    """The measured study's Bode figure on a third-order lag 1/((s+1)(0.1s+1)(0.05s+1)) whose
    phase falls past -180 deg above 2 Hz: the model curve equals the analytic phase (to 1e-9
    deg), a second model (a 1 ms lag more) starts on the same branch, and the measured
    points (the first model times exp(-10 deg j)) lie exactly 10 deg below the curve also
    where np.angle wraps them to +160 deg (the old figure drew np.angle's values: 360 deg
    off there); |H| in deg/(N m), 180/pi times the SI values; no layout problems."""
    from bikeid.experiments.measured.study_plots import _bode_figure

    f = np.logspace(-2, 1.5, 200)
    w = 2 * np.pi * f
    den = np.polymul(np.polymul([1, 1], [0.1, 1]), [0.05, 1])
    a, b = _tf([1], den, w), _tf([0.001, 1], np.polymul(den, [0.002, 1]), w)
    pick = np.arange(20, 200, 30)
    meas = a[pick] * np.exp(-1j * np.radians(10))
    frf = {"speed": 4.0, "models": {"whipple": {"f": f, "phi": a}, "fit": {"f": f, "phi": b}},
           "outputs": {"phi": {"f": f[pick], "H": meas, "rel_error": np.full(pick.size, 0.1)}}}
    _bode_figure(frf, tmp_path / "bode.png")
    fig = captured["bode.png"]
    assert layout_problems(fig) == []
    mag, ph = fig.axes[0], fig.axes[1]
    assert mag.get_ylabel() == "|H| [deg/(N m)]"
    np.testing.assert_allclose(mag.lines[0].get_ydata(), np.degrees(np.abs(a)), rtol=1e-12)
    pa, pb = ph.lines[0].get_ydata(), ph.lines[1].get_ydata()
    exact = -np.degrees(np.arctan(w) + np.arctan(0.1 * w) + np.arctan(0.05 * w))
    np.testing.assert_allclose(pa, exact, atol=1e-9)
    assert abs(pb[0] - pa[0]) < 0.1 and pa[pick].min() < -180  # points past the cut
    np.testing.assert_allclose(ph.lines[2].get_ydata(), pa[pick] - 10, atol=1e-9)


# --- figure formats ----------------------------------------------------------------------------
#: The supported suffixes as the refusal lists them.
ENDINGS = ".png, .pdf, .svg, .eps or .ps"


def _format_of(data: bytes) -> str:
    """A file's format from its leading bytes, by each format's own specification: the PNG
    signature (PNG spec 5.2), the PDF header "%PDF-" (ISO 32000 7.5.2), an XML document whose
    root is <svg> (SVG 1.1), the DSC header "%!PS-Adobe-3.0", with " EPSF-3.0" on the first
    line for EPS (Adobe DSC 3.0 / EPSF 3.0)."""
    first = data.split(b"\n", 1)[0]
    if data.startswith(b"\x89PNG\r\n\x1a\n"):
        return "png"
    if data.startswith(b"%PDF-"):
        return "pdf"
    if data.lstrip().startswith(b"<?xml") and b"<svg" in data[:2000]:
        return "svg"
    if first.startswith(b"%!PS-Adobe-3.0"):
        return "eps" if b"EPSF-3.0" in first else "ps"
    return "unknown"


@pytest.mark.parametrize("fmt", plots.FIGURE_FORMATS)
def test_save_writes_the_format_the_suffix_names(fmt, tmp_path):
    """save() writes each supported format, upper-case suffixes too, as its leading bytes
    show (an independent reading of the file: _format_of)."""
    for name in (f"f.{fmt}", f"G.{fmt.upper()}"):
        fig, ax = plt.subplots()
        ax.plot([0, 1], [0, 1])
        path = plots.save(fig, tmp_path / name)
        assert _format_of(path.read_bytes()) == fmt, name


def test_save_refuses_a_suffix_naming_no_format(tmp_path):
    """An unknown suffix (and none at all) is refused in one line listing the supported
    suffixes; nothing is written and the figure is closed."""
    from bikeid.sim.errors import InputError

    for name, what in (("f.txt", "unsupported figure format '.txt'"),
                       ("f", "no suffix naming a format")):  # fmt: skip
        fig, _ = plt.subplots()
        with pytest.raises(InputError) as exc:
            plots.save(fig, tmp_path / name)
        assert str(exc.value).endswith(f"{what}; give a file name ending in {ENDINGS}")
        assert "\n" not in str(exc.value) and not plt.fignum_exists(fig.number)
    assert list(tmp_path.iterdir()) == []


def test_eig_plot_format_follows_the_suffix(tmp_path):
    """``bikeid eig --plot`` writes SVG, PDF, PNG (and EPS, PS) as the file name says (exit
    0), the bytes read independently (_format_of); an unknown suffix is refused with exit 3
    in one line listing the supported ones, before any work: the bicycle file named with it
    does not exist, and a refusal after loading would name that file instead."""
    for fmt in ("svg", "pdf", "png", "eps", "ps"):
        rc, _, err = _cli(["eig", "--speeds", "0:2:0.5", "--plot", f"eig.{fmt}"], tmp_path)
        assert rc == 0, err
        assert _format_of((tmp_path / f"eig.{fmt}").read_bytes()) == fmt
    rc, out, err = _cli(["eig", "--bicycle", "missing.yaml", "--plot", "eig.jpg"], tmp_path)
    assert rc == 3 and out == "" and len(err.strip().splitlines()) == 1, err
    assert f"--plot eig.jpg: unsupported figure format '.jpg'; give a file name ending in " \
        f"{ENDINGS}" in err
    assert not (tmp_path / "eig.jpg").exists()


# --- identify --plot --------------------------------------------------------------------------


def _cli(argv, cwd: Path):
    from bikeid.experiments.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        rc = main(list(map(str, argv)))
    return rc, out.getvalue(), err.getvalue()


def _logger_csv(path: Path, run) -> Path:
    """An ordinary logger's CSV: ms, degrees, km/h, roll positive left."""
    table = np.column_stack([1000 * run.t, -np.degrees(run["phi"]), -np.degrees(run["phidot"]),
                             np.degrees(run["delta"]), np.degrees(run["deltadot"]),
                             3.6 * run["v"], run["T_delta"]])  # fmt: skip
    with path.open("w") as fh:
        fh.write("Time_ms,Roll_deg,RollRate_dps,Steer_deg,SteerRate_dps,Speed_kmh,SteerTorque_Nm\n")
        np.savetxt(fh, table, delimiter=",", fmt="%.12g")
    return path


LOGGER = ["--format", "csv", "--columns",
          "phi=Roll_deg,phidot=RollRate_dps,delta=Steer_deg,deltadot=SteerRate_dps,"
          "v=Speed_kmh,T_delta=SteerTorque_Nm",
          "--units", "phi=deg,phidot=deg/s,delta=deg,deltadot=deg/s,v=km/h,t=ms",
          "--time", "Time_ms", "--flip", "phi,phidot"]  # fmt: skip


def test_identify_plot_draws_intervals_against_the_nominal(tmp_path, monkeypatch):
    """``identify --plot`` on two logger CSVs (4 and 6 m/s, a model over speed): the figure
    is written and fits (no layout problems); its complex-plane dots are the identified
    eigenvalues printed in --json, its open squares the benchmark's Whipple eigenvalues
    (sim.linear, to 1e-12), the error bars span the printed 95 % intervals; a --plot that is
    written as SVG because its name ends in .svg; a --plot whose suffix names no figure
    format is refused (exit 3, one line listing the supported suffixes) before any work."""
    for v in (4.0, 6.0):
        _logger_csv(tmp_path / f"r{v:g}.csv",
                    simulate(P, v, duration=20, seed=1, rate_noise=1e-3, angle_noise=1e-4))
    figs = {}
    real_save = plots.save

    def keep(fig, path):
        figs["fig"] = layout_problems(fig), list(fig.axes[0].lines), fig.axes[0].containers
        return real_save(fig, path)

    monkeypatch.setattr(plots, "save", keep)
    argv = ["identify", "r4.csv", "r6.csv", *LOGGER, "--method", "pem", "--speed-parameterized",
            "--plot", "eig.svg", "--json"]  # fmt: skip
    rc, out, err = _cli(argv, tmp_path)
    assert rc == 0, err
    doc = json.loads(out)
    assert doc["plot"] == "eig.svg" and (tmp_path / "eig.svg").stat().st_size > 10000
    assert _format_of((tmp_path / "eig.svg").read_bytes()) == "svg"
    problems, lines, bars = figs["fig"]
    assert problems == []
    squares = [ln for ln in lines if ln.get_marker() == "s"]
    dots = [ln for ln in lines if ln.get_marker() == "o"]
    for k, row in enumerate(doc["per_speed"]):
        nom = eigenvalues(P, row["speed"])
        sq = squares[k].get_xdata() + 1j * squares[k].get_ydata()
        np.testing.assert_allclose(np.sort_complex(sq), np.sort_complex(nom), atol=1e-12)
        got = np.array([complex(z["re"], z["im"]) for z in row["eigenvalues"]])
        drawn = dots[k].get_xdata() + 1j * dots[k].get_ydata()
        np.testing.assert_allclose(match_eigenvalues(drawn, got), got, atol=1e-12)
        # the horizontal bars: each eigenvalue's 95 % real-part interval, as printed
        xbars = bars[k].lines[2][0].get_segments()
        ends = sorted((min(sg[:, 0]), max(sg[:, 0])) for sg in xbars)
        printed = sorted(tuple(r["real"]) for r in row["eigenvalue_intervals"]["eigenvalues"])
        np.testing.assert_allclose(ends, printed, atol=1e-9)
    for name, what in (("eig.txt", "unsupported figure format '.txt'"),
                       ("eig", "no suffix naming a format")):  # fmt: skip
        rc, _, err = _cli(["identify", "r4.csv", *LOGGER, "--plot", name], tmp_path)
        assert rc == 3 and len(err.strip().splitlines()) == 1, err
        assert f"--plot {name}: {what}; give a file name ending in {ENDINGS}" in err, err
        assert not (tmp_path / name).exists()


def test_validate_draws_in_the_users_unit(run, captured, tmp_path):
    """``bikeid validate`` on the same ride logged in radians (no unit declared) and in
    degrees (declared): the compare figure's roll axis is in the log's unit, and the drawn
    values are the logged ones (to the CSV's 12 significant digits)."""
    from bikeid.ident.canonical import theta_from_matrices
    from bikeid.ident.model_file import save_model
    from bikeid.ident.pem import CanonicalModel
    from bikeid.sim.linear import canonical_matrices

    theta = theta_from_matrices(canonical_matrices(P), 5.0)
    model = CanonicalModel(theta=theta, covariance=np.diag((0.05 * theta) ** 2),
                           K=np.zeros((4, 4)), dt=run.dt, speed=5.0, noise_covariance=np.eye(4),
                           outputs=("phi", "delta", "phidot", "deltadot"))  # fmt: skip
    save_model(model, tmp_path / "m.json")
    cols = ",".join(f"{k}={v}" for k, v in COLS.items())
    units = ",".join(f"{k}={v}" for k, v in DEG_UNITS.items())
    for name, degrees, extra in (("rad", False, []), ("deg", True, ["--units", units])):
        _csv(tmp_path / f"{name}.csv", run, degrees)
        captured.clear()
        rc, _, err = _cli(["validate", "--model", "m.json", f"{name}.csv", "--format", "csv",
                           "--columns", cols, *extra, "--out", f"val_{name}"],
                          tmp_path)  # fmt: skip
        assert rc == 0, err
        ax = captured["compare_1.png"].axes[0]
        assert ax.get_ylabel() == f"phi [{name}]"
        logged = np.loadtxt(tmp_path / f"{name}.csv", delimiter=",", skiprows=1)[:, 1]
        np.testing.assert_allclose(ax.lines[0].get_ydata(), logged, rtol=1e-10, atol=1e-15)
