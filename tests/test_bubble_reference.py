"""The rising bubble's reference data: the stored values follow from the stored series.

``docs/data/rising-bubble/hysing2009.csv`` holds the values the metrics compare with
(``pfem2x.cases.HYSING_BUBBLE``); its MooNMD rows must be what the group's time series in
``docs/data/rising-bubble/moonmd/`` give, and ``benchmarks/bubble_plot.py`` measures runs
against those series and the shapes at t = 3.
"""

import csv
import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from pfem2x.cases import BUBBLE_SERIES, HYSING_BUBBLE, RisingBubbleCase, moonmd_series

ROOT = Path(__file__).resolve().parent.parent
DATA = ROOT / "docs" / "data" / "rising-bubble"


def _plot_module():
    spec = importlib.util.spec_from_file_location("bubble_plot", ROOT / "benchmarks/bubble_plot.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _rows() -> list[dict[str, str]]:
    with open(DATA / "hysing2009.csv", newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.parametrize("case", [1, 2])
def test_moonmd_values_are_read_off_its_series(case):
    mod = _plot_module()
    s = mod.read_series(DATA / "moonmd", case)
    win = s["t"] <= 3.0
    assert s["t"][0] < 0.01 and s["t"][win][-1] > 2.99 and abs(s["centroid_y"][0] - 0.5) < 1e-5
    got = {r["quantity"]: r for r in _rows() if r["group"] == "MooNMD" and int(r["case"]) == case}
    y3 = np.interp(3.0, s["t"], s["centroid_y"])
    assert float(got["centroid_y_final"]["value"]) == pytest.approx(y3, abs=6e-6)
    first = win & (s["t"] < 1.5)  # case 2 has a second, lower maximum after t = 1.5
    k = int(np.argmax(np.where(first, s["rise_velocity"], -1.0)))
    assert float(got["rise_velocity_max"]["value"]) == pytest.approx(
        s["rise_velocity"][k], abs=6e-6
    )
    assert float(got["rise_velocity_max"]["time"]) == pytest.approx(s["t"][k], abs=1e-4)
    assert s["rise_velocity"][k] == s["rise_velocity"][win].max()
    circ3 = np.interp(3.0, s["t"], s["circularity"])
    cmin = min(s["circularity"][win].min(), circ3)
    assert float(got["circularity_min"]["value"]) == pytest.approx(cmin, abs=6e-6)
    if case == 2:
        late = win & (s["t"] > 1.5)
        k = int(np.argmax(np.where(late, s["rise_velocity"], -1.0)))
        assert float(got["rise_velocity_max2"]["value"]) == pytest.approx(
            s["rise_velocity"][k], abs=6e-6
        )
        assert float(got["rise_velocity_max2"]["time"]) == pytest.approx(s["t"][k], abs=1e-4)
    shape = mod.read_shape(DATA / "moonmd", case)
    assert shape.shape[1] == 2 and np.allclose(shape[0], shape[-1], atol=1e-3)  # closed


def test_metrics_compare_with_the_stored_values():
    rows = _rows()
    for case, group in ((1, "TP2D"), (2, "MooNMD")):
        stored = {
            r["quantity"]: float(r["value"])
            for r in rows
            if int(r["case"]) == case and r["group"] == group
        }
        assert {k: stored[k] for k in HYSING_BUBBLE[case]} == HYSING_BUBBLE[case]
    # TP2D's values of test case 1 against MooNMD's series: the groups agree to 0.05 %
    moon = {
        r["quantity"]: float(r["value"])
        for r in rows
        if r["group"] == "MooNMD" and int(r["case"]) == 1
    }
    for k, v in HYSING_BUBBLE[1].items():
        assert abs(v - moon[k]) / v < 5e-4, k


def test_case_two_runs_get_relative_errors():
    """A test case 2 run to t = 3 gets the three relative errors against MooNMD."""
    solver = SimpleNamespace(scene=SimpleNamespace(params={"case": 2}))
    case = RisingBubbleCase(solver)
    ref = HYSING_BUBBLE[2]
    t = np.linspace(0.0, 3.0, 31)
    hist = [
        {
            "t": ti,
            "centroid_y": 0.5 + (ref["centroid_y_final"] * 1.01 - 0.5) * ti / 3.0,
            "rise_velocity": ref["rise_velocity_max"] * 0.98 * np.sin(np.pi * ti / 3.0),
            "circularity": 1.0 - (1.0 - ref["circularity_min"]) * ti / 3.0,
        }
        for ti in t
    ]
    m = case.metrics(hist)
    assert m["centroid_y_final_rel_error"] == pytest.approx(0.01, rel=1e-9)
    assert m["rise_velocity_max_rel_error"] == pytest.approx(0.02, rel=1e-9)
    assert m["circularity_min_rel_error"] == pytest.approx(0.0, abs=1e-12)
    assert "centroid_y_final_rel_error" not in case.metrics(hist[:-1])  # t_end < 3


def test_shape_distance():
    """The Hausdorff distance of two concentric circles is their radii's difference."""
    mod = _plot_module()
    a = np.linspace(0.0, 2.0 * np.pi, 2001)
    circle = np.c_[0.5 + 0.25 * np.cos(a), 0.5 + 0.25 * np.sin(a)]
    b = np.linspace(0.0, 2.0 * np.pi, 301)
    bigger = np.c_[0.5 + 0.26 * np.cos(b), 0.5 + 0.26 * np.sin(b)]
    h, mean = mod.shape_distance([bigger], circle)
    assert h == pytest.approx(0.01, abs=1e-6) and mean == pytest.approx(0.01, abs=1e-6)
    # an open arc: the far part of the reference is far from it
    h, _ = mod.shape_distance([bigger[: len(bigger) // 2]], circle)
    assert h > 0.35  # (0.5, 0.25) to the arc's ends: about sqrt(0.25² + 0.26²)
    h, _ = mod.shape_distance([circle, np.array([[0.5, 0.9]])], circle)  # a droplet
    assert h == pytest.approx(0.15, abs=1e-6)


@pytest.mark.parametrize("case", [1, 2])
def test_packaged_series_is_moonmd_resampled(case):
    """The package's series (the curve metrics') is MooNMD's, at t = 0, 0.01, ..., 3."""
    mod = _plot_module()
    full = mod.read_series(DATA / "moonmd", case)
    pkg = moonmd_series(case)
    assert pkg["t"][0] == 0.0 and pkg["t"][-1] == pytest.approx(3.0)
    assert np.allclose(np.diff(pkg["t"]), 0.01)
    t0 = {"centroid_y": 0.5, "rise_velocity": 0.0, "circularity": 1.0}
    for k in BUBBLE_SERIES:
        ref = np.interp(pkg["t"], np.r_[0.0, full["t"]], np.r_[t0[k], full[k]])
        assert np.abs(pkg[k] - ref).max() < 1e-6, k  # (6 decimals stored)
    assert moonmd_series(3) is None


def test_curve_errors_are_the_largest_differences_to_moonmd():
    """A run that is MooNMD's series plus a known offset gets that offset back."""
    ref = moonmd_series(1)
    case = RisingBubbleCase(SimpleNamespace(scene=SimpleNamespace(params={"case": 1})))
    t = np.linspace(0.0, 3.0, 61)
    offs = {"centroid_y": 0.002, "rise_velocity": -0.003, "circularity": 0.004}
    hist = [
        {k: float(np.interp(ti, ref["t"], ref[k])) + offs[k] * ti / 3.0 for k in BUBBLE_SERIES}
        | {"t": ti}
        for ti in t
    ]
    hist.append(dict(hist[-1], t=3.2, centroid_y=5.0))  # after t = 3: not compared
    m = case.metrics(hist)
    for k, v in offs.items():
        assert m[f"{k}_curve_error"] == pytest.approx(abs(v), abs=1e-9), k
    assert "centroid_y_curve_error" not in case.metrics(hist[:30])  # t_end < 3


def _fake_run(folder: Path, case: int) -> Path:
    """A run folder whose series and outline at t = 3 are MooNMD's own."""
    mod = _plot_module()
    ref = moonmd_series(case)
    folder.mkdir(parents=True)
    (folder / "scene.toml").write_text(f"[params]\ncase = {case}\n")
    (folder / "summary.json").write_text('{"status": "ok", "metrics": {}}')
    t = np.round(np.arange(0.0, 3.0 + 1e-9, 0.1), 10)
    with open(folder / "diagnostics.csv", "w") as f:
        f.write("t,centroid_y,rise_velocity,circularity\n")
        for ti in t:
            vals = [np.interp(ti, ref["t"], ref[k]) for k in BUBBLE_SERIES]
            f.write(f"{ti}," + ",".join(f"{v:.10f}" for v in vals) + "\n")
    (folder / "interface").mkdir()
    a = np.linspace(0.0, 2.0 * np.pi, 65)
    circle = np.c_[0.5 + 0.25 * np.cos(a), 0.5 + 0.25 * np.sin(a)]
    for name, pts in (
        ("interface_t0000.00000.csv", circle),
        ("interface_t0003.00000.csv", mod.read_shape(DATA / "moonmd", case)),
    ):
        rows = "".join(f"0,{x},{y}\n" for x, y in pts)
        (folder / "interface" / name).write_text("line,x,y\n" + rows)
    return folder


def test_bubble_plot_of_a_run_that_is_the_reference(tmp_path, capsys):
    """MooNMD's own series and outline, run through the plot script: differences ~0."""
    mod = _plot_module()
    for case in (1, 2):
        run = _fake_run(tmp_path / f"c{case}", case)
        out = tmp_path / f"c{case}.png"
        assert mod.main([str(out), f"MooNMD itself={run}"]) == 0
        assert out.stat().st_size > 0
        row = capsys.readouterr().out.strip().splitlines()[-1].split("|")
        assert row[1].strip() == "MooNMD itself"
        assert all(float(c) < 1e-5 for c in row[2:7]), row
    # runs of both test cases in one figure: one error line, exit 2, nothing written
    bad = tmp_path / "mixed.png"
    spec = [f"a={tmp_path / 'c1'}", f"b={tmp_path / 'c2'}"]
    assert mod.main([str(bad), *spec]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and not bad.exists()


def test_interfoam_series_curve_table(capsys, benchmark_script):
    """The stored interFoam series against MooNMD: one row each; a bad file is one error."""
    mod = benchmark_script("interfoam_bubble")
    files = sorted((DATA / "interfoam").glob("series_n*.csv"))
    assert len(files) == 9
    mod.main(["curves", *map(str, files)])
    rows = capsys.readouterr().out.strip().splitlines()[2:]
    assert [r.split("|")[1].strip() for r in rows] == [f.name for f in files]
    y = {r.split("|")[1].strip(): float(r.split("|")[2]) for r in rows}
    # interFoam's centroid: closer to MooNMD at the smaller steps (first order in dt)
    assert y["series_n40_cap0.25.csv"] < y["series_n40_cap1.csv"] < y["series_n40.csv"]
    # and not with the mesh: h = 1/160 at half its capillary limit stays farther than 1/80 at
    # a quarter of its limit
    assert y["series_n160_cap0.5.csv"] > y["series_n80_cap0.25.csv"]
    with pytest.raises(SystemExit) as e:
        mod.main(["curves", str(DATA / "no-such.csv")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "no-such.csv" in err[0]
