"""Output helpers: particle VTK files, interface polylines."""

from pathlib import Path

import numpy as np
import pytest

from pfem2x.compat import MPI
from pfem2x.io import chain_segments, read_interface, write_interface, write_pvtp, write_vtp
from pfem2x.runner import Simulation
from pfem2x.scene import load_scene


def test_chain_segments_open_and_closed():
    rng = np.random.default_rng(0)
    # an open zig-zag of 6 points and a closed square, segments shuffled and flipped
    line = np.array([[0, 0], [1, 0.5], [2, 0], [3, 0.5], [4, 0], [5, 0.5]], float)
    sq = np.array([[10, 10], [11, 10], [11, 11], [10, 11], [10, 10]], float)
    segs = [np.array([a, b]) for a, b in zip(line[:-1], line[1:], strict=True)]
    segs += [np.array([a, b]) for a, b in zip(sq[:-1], sq[1:], strict=True)]
    segs = [s[::-1] if rng.random() < 0.5 else s for s in segs]
    order = rng.permutation(len(segs))
    lines = chain_segments(np.array(segs)[order])
    assert sorted(len(ln) for ln in lines) == [5, 6]
    open_line = next(ln for ln in lines if len(ln) == 6)
    assert {tuple(open_line[0]), tuple(open_line[-1])} == {(0.0, 0.0), (5.0, 0.5)}
    closed = next(ln for ln in lines if len(ln) == 5)
    assert np.allclose(closed[0], closed[-1])


def _chain_reference(segs, tol=1e-9):
    """The walk of :func:`chain_segments` written plainly (dicts and lists)."""
    pts = segs.reshape(-1, 2)
    scale = max(float(np.ptp(pts, axis=0).max()), 1.0)
    keys = [tuple(k) for k in np.round(pts / (tol * scale)).astype(np.int64).tolist()]
    ids = [sorted(set(keys)).index(k) for k in keys]
    nbrs, point = {}, {}
    for i, v in enumerate(ids):
        nbrs.setdefault(v, []).append(i // 2)
        point[v] = pts[i]
    used = [False] * len(segs)
    lines = []
    for v0 in [v for v, ks in nbrs.items() if len(ks) == 1] + list(nbrs):
        while not all(used[k] for k in nbrs[v0]):
            lines.append(_walk(v0, nbrs, ids, used, point))
    return lines


def _walk(v0, nbrs, ids, used, point):
    line, v = [v0], v0
    while nxt := [k for k in nbrs[v] if not used[k]]:
        used[nxt[0]] = True
        a, b = ids[2 * nxt[0]], ids[2 * nxt[0] + 1]
        v = b if a == v else a
        line.append(v)
    return np.array([point[i] for i in line])


def test_chain_segments_walks_junctions_and_loops_as_the_plain_walk():
    """Random segments on a small lattice (junctions of 3-6 segments, loops, repeated and
    zero-length segments, end points that differ by less than the tolerance): the same
    polylines as the plain walk, and every segment in one of them (a walk from a
    junction once only left some out)."""
    rng = np.random.default_rng(3)
    for trial in range(60):
        n = int(rng.integers(1, 40))
        segs = rng.integers(0, 6, size=(n, 2, 2)) * 0.5 - 1.0
        if trial % 2:
            segs = segs + rng.random(segs.shape) * 1e-12
        lines = chain_segments(segs)
        expected = _chain_reference(segs)
        assert len(lines) == len(expected)
        for got, want in zip(lines, expected, strict=True):
            assert np.array_equal(got, want)
        assert sum(len(ln) - 1 for ln in lines) == n  # every segment once


def _vtp_parts(path):
    """The XML tree of a ``.vtp`` file (its appended block emptied) and that block's bytes."""
    import xml.etree.ElementTree as ET

    raw = Path(path).read_bytes()
    tag = b'<AppendedData encoding="raw">'
    head, rest = raw.split(tag)
    start = rest.index(b"_") + 1
    end = rest.rindex(b"</AppendedData>")
    tail = b"</AppendedData>" + rest[end + len(b"</AppendedData>") :]
    return ET.fromstring(head + tag + tail), rest[start:end].rstrip(b"\n")


def test_vtp_is_valid_xml(tmp_path):
    p = tmp_path / "p.vtp"
    write_vtp(
        p, np.random.default_rng(1).random((10, 2)), {"T": np.arange(10.0), "u": np.ones((10, 2))}
    )
    root, _ = _vtp_parts(p)
    piece = root.find("PolyData/Piece")
    assert piece.get("NumberOfPoints") == "10"
    names = [a.get("Name") for a in root.iter("DataArray")]
    assert "T" in names and "u" in names


def _read_vtp(path):
    """The arrays of a VTK XML PolyData file with appended raw data, decoded by hand."""
    types = {"Float32": np.float32, "Float64": np.float64, "Int32": np.int32, "Int64": np.int64}
    root, block = _vtp_parts(path)
    assert root.get("header_type") == "UInt64"
    out, end = {}, 0
    for a in root.iter("DataArray"):
        assert a.get("format") == "appended" and not (a.text or "").strip()
        at = int(a.get("offset"))
        assert at == end  # the blocks follow each other in the order declared
        nbytes = int(np.frombuffer(block[at : at + 8], dtype=np.uint64)[0])
        end = at + 8 + nbytes
        vals = np.frombuffer(block[at + 8 : end], dtype=types[a.get("type")])
        out[a.get("Name") or "Points"] = (
            a.get("type"),
            vals.reshape(-1, int(a.get("NumberOfComponents"))),
        )
    assert end == len(block)
    return out


def test_vtk_reads_the_particle_file(tmp_path):
    """VTK's own XML reader (ParaView's) reads what :func:`write_vtp` wrote."""
    vtk = pytest.importorskip("vtkmodules.vtkIOXML")
    from vtkmodules.util.numpy_support import vtk_to_numpy

    rng = np.random.default_rng(4)
    n = 1000
    pos, u, label = rng.random((n, 2)), rng.random((n, 2)), np.arange(n, dtype=np.int64)
    write_vtp(tmp_path / "p.vtp", pos, {"u": u, "phase": u[:, 0], "label": label}, "double")
    reader = vtk.vtkXMLPolyDataReader()
    reader.SetFileName(str(tmp_path / "p.vtp"))
    reader.Update()
    out = reader.GetOutput()
    assert out.GetNumberOfPoints() == n and out.GetNumberOfVerts() == n
    assert np.array_equal(vtk_to_numpy(out.GetPoints().GetData())[:, :2], pos)
    pd = out.GetPointData()
    assert np.array_equal(vtk_to_numpy(pd.GetArray("u"))[:, :2], u)
    assert np.array_equal(vtk_to_numpy(pd.GetArray("phase")), u[:, 0])
    assert np.array_equal(vtk_to_numpy(pd.GetArray("label")), label)


@pytest.mark.parametrize("precision", ["single", "double"])
def test_vtp_round_trip(tmp_path, precision):
    rng = np.random.default_rng(2)
    n = 37
    pos, u, phase = rng.random((n, 2)), rng.random((n, 2)), rng.random((n, 1))
    label = np.arange(n, dtype=np.int64)
    write_vtp(tmp_path / "p.vtp", pos, {"u": u, "phase": phase, "label": label}, precision)
    got = _read_vtp(tmp_path / "p.vtp")
    typ, tol = ("Float32", 1e-7) if precision == "single" else ("Float64", 0.0)
    assert got["Points"][0] == typ and got["u"][0] == typ and got["phase"][0] == typ
    assert np.abs(got["Points"][1][:, :2] - pos).max() <= tol and not got["Points"][1][:, 2].any()
    assert np.abs(got["u"][1][:, :2] - u).max() <= tol and got["u"][1].shape == (n, 3)
    assert got["phase"][1].shape == (n, 1) and np.abs(got["phase"][1] - phase).max() <= tol
    assert got["label"][0] == "Int64" and np.array_equal(got["label"][1].ravel(), label)
    assert np.array_equal(got["connectivity"][1].ravel(), np.arange(n))
    assert np.array_equal(got["offsets"][1].ravel(), np.arange(1, n + 1))
    with pytest.raises(ValueError, match="precision"):
        write_vtp(tmp_path / "q.vtp", pos, {}, "half")


def _pieces(pvtp):
    """The declared arrays (name -> type) and the pieces' decoded arrays of a .pvtp file."""
    import xml.etree.ElementTree as ET

    root = ET.parse(pvtp).getroot()
    decl = {a.get("Name") or "Points": a.get("type") for a in root.iter("PDataArray")}
    return decl, [_read_vtp(pvtp.parent / p.get("Source")) for p in root.iter("Piece")]


def test_pvtp_declares_its_pieces_arrays(tmp_path):
    rng = np.random.default_rng(3)
    pieces = []
    for r, n in enumerate([5, 0, 7]):  # an empty piece as on a rank without particles
        pos, u = rng.random((n, 2)), rng.random((n, 2))
        write_vtp(tmp_path / f"p_r{r}.vtp", pos, {"u": u, "phase": u[:, 0]}, "single")
        pieces.append((pos, u))
    write_pvtp(
        tmp_path / "p.pvtp",
        ["p_r0.vtp", "p_r1.vtp", "p_r2.vtp"],
        pos,
        {"u": u, "phase": u[:, 0]},
        "single",
    )
    decl, got = _pieces(tmp_path / "p.pvtp")
    assert decl == {"u": "Float32", "phase": "Float32", "Points": "Float32"}
    for g, (pos, u) in zip(got, pieces, strict=True):
        assert {k: v[0] for k, v in g.items() if k in decl} == decl
        assert np.abs(g["Points"][1][:, :2] - pos).max(initial=0.0) <= 1e-7
        assert np.abs(g["u"][1][:, :2] - u).max(initial=0.0) <= 1e-7
    try:  # VTK's parallel reader (ParaView's) joins the pieces, the empty one too
        from vtkmodules.util.numpy_support import vtk_to_numpy
        from vtkmodules.vtkIOXML import vtkXMLPPolyDataReader
    except ImportError:
        return
    reader = vtkXMLPPolyDataReader()
    reader.SetFileName(str(tmp_path / "p.pvtp"))
    reader.Update()
    out = reader.GetOutput()
    joined = np.concatenate([pos for pos, _ in pieces])
    assert out.GetNumberOfPoints() == len(joined) and out.GetNumberOfVerts() == len(joined)
    assert np.abs(vtk_to_numpy(out.GetPoints().GetData())[:, :2] - joined).max() <= 1e-7
    u_all = np.concatenate([u for _, u in pieces])
    assert np.abs(vtk_to_numpy(out.GetPointData().GetArray("u"))[:, :2] - u_all).max() <= 1e-7


@pytest.mark.mpi
def test_particle_files_of_a_parallel_run_are_one_piece_per_rank(shared_tmp):
    sc = load_scene("rayleigh-taylor", ["output.png=false"], "small")
    sim = Simulation(sc, shared_tmp / "rt", quiet=True)
    res = sim.run()
    comm = MPI.COMM_WORLD
    counts = [int(c) for c in comm.allgather(sim.solver.cloud().x.shape[0])]
    found = None
    if comm.rank == 0:  # read on rank 0, checked on every rank
        out = shared_tmp / "rt"
        pvd = (out / "particles.pvd").read_text()
        ext = ".pvtp" if comm.size > 1 else ".vtp"
        files = sorted((out / "particles").glob(f"*{ext}"))
        if comm.size > 1:
            decl, got = _pieces(files[-1])
            sizes = [g["Points"][1].shape[0] for g in got]
        else:
            sizes = [_read_vtp(files[-1])["Points"][1].shape[0]]
        found = (res.status, f'file="particles/{files[-1].name}"' in pvd, sizes)
    status, listed, sizes = comm.bcast(found, root=0)
    assert status == "ok" and listed
    assert sizes == counts  # each rank's particles in its own piece, none gathered


@pytest.mark.mpi
def test_interface_polylines_of_a_run(shared_tmp):
    sc = load_scene("rayleigh-taylor", ["output.png=false", "output.particles=false"], "small")
    res = Simulation(sc, shared_tmp / "rt", quiet=True).run()
    assert res.status == "ok"
    # read on rank 0 (which wrote them), checked on every rank: a rank must not fail alone
    # before the collectives below
    comm = MPI.COMM_WORLD
    found = None
    if comm.rank == 0:
        files = sorted((shared_tmp / "rt" / "interface").glob("interface_t*.csv"))
        found = (len(files), read_interface(files[-1]) if files else [])
    n_files, lines = comm.bcast(found, root=0)
    assert n_files == 2  # start and end (output.every = 0 in the small variant)
    # one interface from wall to wall, gathered across ranks into a single polyline
    assert len(lines) == 1
    xs = lines[0][:, 0]
    assert xs.min() == pytest.approx(-0.5) and xs.max() == pytest.approx(0.5)
    # also the writer alone, with an empty rank
    segs = np.array([[[0.0, 0.0], [1.0, 0.0]]]) if MPI.COMM_WORLD.rank == 0 else np.zeros((0, 2, 2))
    write_interface(MPI.COMM_WORLD, shared_tmp / "one.csv", segs)
    MPI.COMM_WORLD.Barrier()
    assert len(read_interface(shared_tmp / "one.csv")) == 1
