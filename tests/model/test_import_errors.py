"""`fabline import`: the command's output, and every bad input named on one line with exit code 2 and no output file."""

from __future__ import annotations

import json

import ezdxf
import numpy as np
import pytest

from fabline.model import load_network, network_to_dict, save_network
from fabline.model.writers import write_dxf, write_obj
from .test_import_roundtrip import hypar_mesh, hypar_network


@pytest.fixture(scope="module")
def surface(tmp_path_factory):
    path = tmp_path_factory.mktemp("surface") / "surface.obj"
    hypar_mesh(count=41).export(path)
    return path


def obj_text(curves: dict[str, list[tuple[float, float, float]]]) -> str:
    """An OBJ file with one `l` polyline per named curve: `o NAME`, its `v` lines, then the `l` line."""
    lines, count = [], 0
    for name, points in curves.items():
        lines.append(f"o {name}")
        lines.extend(f"v {x} {y} {z}" for x, y, z in points)
        lines.append("l " + " ".join(str(count + k + 1) for k in range(len(points))))
        count += len(points)
    return "\n".join(lines) + "\n"


def line(p, q, n=5):
    return [tuple(float(v) for v in np.asarray(p) + t * (np.asarray(q) - np.asarray(p))) for t in np.linspace(0, 1, n)]


def test_import_command_writes_the_model_and_prints_a_summary(cli, tmp_path, surface):
    network = hypar_network(count=4)
    write_obj(network, tmp_path / "curves.obj")
    out = tmp_path / "model.network.json"
    code, stdout, stderr = cli("import", tmp_path / "curves.obj", "--surface", surface, "--units", "m", "-o", out)
    assert code == 0 and stderr == ""
    assert "8 lamellas, 16 nodes (0 singularities), units m" in stdout
    assert "crossings within 1 mm; 0 near-miss(es)" in stdout and f"wrote {out}" in stdout
    model = load_network(out)
    assert len(model.nodes) == 16 and {lam.id for lam in model.lamellas} == {lam.id for lam in network.lamellas}


def test_import_of_json_validates_and_rewrites(cli, tmp_path, surface):
    network = hypar_network(count=3)
    write_obj(network, tmp_path / "c.obj")
    cli("import", tmp_path / "c.obj", "--surface", surface, "-o", tmp_path / "a.json")
    code, stdout, _ = cli("import", tmp_path / "a.json", "-o", tmp_path / "b.json")
    assert code == 0 and "(json): 6 lamellas, 9 nodes" in stdout
    assert load_network(tmp_path / "b.json").nodes.keys() == load_network(tmp_path / "a.json").nodes.keys()


def _write(tmp_path, name, text):
    path = tmp_path / name
    path.write_text(text)
    return path


def _dxf_in(units_code, tmp_path, name="curves.dxf"):
    network = hypar_network(count=3)
    write_dxf(network, tmp_path / name)
    doc = ezdxf.readfile(tmp_path / name)
    doc.header["$INSUNITS"] = units_code
    doc.saveas(tmp_path / name)
    return tmp_path / name


CROSS = {"A-1": line((-1, 0, 0), (1, 0, 0)), "B-1": line((0, -1, 0), (0, 1, 0))}


def bad_input(case: str, tmp_path, surface):
    """(args after `import`, text expected in the one-line error) for each bad input."""
    if case == "malformed OBJ vertex":
        path = _write(tmp_path, "bad.obj", "o A-1\nv 0 0 0\nv 1 zero 0\nl 1 2\n")
        return [path, "--surface", surface], f"{path}:3: malformed vertex"
    if case == "malformed OBJ reference":
        path = _write(tmp_path, "bad.obj", "o A-1\nv 0 0 0\nv 1 0 0\nl 1 7\n")
        return [path, "--surface", surface], f"{path}:4: vertex 7 does not exist"
    if case == "malformed DXF":
        path = _write(tmp_path, "bad.dxf", "  0\nSECTION\n  2\nENTITIES\n  0\nLINE\n 10\nnot a number\n")
        return [path, "--surface", surface], f"{path}: malformed DXF"
    if case == "NaN coordinate":
        path = _write(tmp_path, "nan.obj", obj_text({**CROSS, "A-2": [(0, 0.5, 0), (float("nan"), 0.5, 0)]}))
        return [path, "--surface", surface], f"{path}: line 18 (A-2): point 1 contains NaN or infinite values"
    if case == "zero-length curve":
        path = _write(tmp_path, "zero.obj", obj_text({**CROSS, "B-2": [(0.5, 0, 0)] * 3}))
        return [path, "--surface", surface], f"{path}: line 19 (B-2): curve has zero length"
    if case == "self-overlapping curve":  # a loop that runs through its own start again
        t = np.linspace(0, 1.25, 51) * 2 * np.pi
        loop = [(0.5 * np.cos(a), 0.5 * np.sin(a), 0.0) for a in t]
        path = _write(tmp_path, "loop.obj", obj_text({**CROSS, "A-2": loop}))
        return [path, "--surface", surface], f"{path}: lamella A-2: curve overlaps itself"
    if case == "curves that never cross":
        path = _write(tmp_path, "apart.obj", obj_text({"A-1": line((-1, 0, 0), (1, 0, 0)),
                                                       "B-1": line((0, 0.5, 0.2), (0, 1, 0.2))}))
        return [path, "--surface", surface], f"{path}: the curves never cross"
    if case == "a lamella that crosses nothing":
        path = _write(tmp_path, "stray.obj", obj_text({**CROSS, "B-2": line((1.5, 1, 0), (1.5, 2, 0))}))
        return [path, "--surface", surface], f"{path}: lamella B-2 (line 21 (B-2)) crosses no lamella"
    if case == "only one family":
        path = _write(tmp_path, "one.obj", obj_text({"A-1": CROSS["A-1"]}))
        return [path, "--surface", surface], f"{path}: no curves of family B"
    if case == "duplicate lamella id":
        text = obj_text({**CROSS}) + "o A-1\nv 0 0.5 0\nv 1 0.5 0\nl 11 12\n"
        path = _write(tmp_path, "dup.obj", text)
        return [path, "--surface", surface], f"{path}: duplicate lamella id A-1"
    if case == "four lamellas at one point":
        path = _write(tmp_path, "four.obj", obj_text({**CROSS, "A-2": line((-1, -1, 0), (1, 1, 0)),
                                                      "B-2": line((-1, 1, 0), (1, -1, 0))}))
        return [path, "--surface", surface], "4 lamellas meet at (0, 0, 0)"
    if case == "a curve drawn twice":
        path = _write(tmp_path, "twice.obj", obj_text({**CROSS, "A-2": CROSS["A-1"]}))
        return [path, "--surface", surface], f"{path}: lamellas A-1 and A-2 (both family A) run together"
    if case == "missing normals":
        path = _write(tmp_path, "bare.obj", obj_text(CROSS))
        return [path], f"{path}: missing normals: give --surface"
    if case == "mixed units: declared":
        path = _dxf_in(4, tmp_path)  # $INSUNITS 4 = mm
        return [path, "--surface", surface, "--units", "m"], f"mixed units: {path} declares mm but --units m"
    if case == "mixed units: surface scale":
        big = tmp_path / "surface_mm.obj"
        mesh = hypar_mesh(count=11)
        mesh.vertices = mesh.vertices * 1000
        mesh.export(big)
        write_obj(hypar_network(count=3), tmp_path / "curves.obj")
        return [tmp_path / "curves.obj", "--surface", big, "--units", "m"], \
            f"mixed units: {big} is 3.76e+03 times the size of the curves in {tmp_path / 'curves.obj'}"
    if case == "mixed units: DXF surface":
        curves = _dxf_in(6, tmp_path)  # m
        doc = ezdxf.new()
        doc.header["$INSUNITS"] = 4
        mesh = hypar_mesh(count=5)
        doc.modelspace().add_3dface(mesh.triangles[0].tolist())
        doc.saveas(tmp_path / "surface.dxf")
        return [curves, "--surface", tmp_path / "surface.dxf"], \
            f"mixed units: {curves} is in m but {tmp_path / 'surface.dxf'} is in mm"
    if case == "unknown file type":
        path = _write(tmp_path, "curves.step", "ISO-10303-21;\n")
        return [path], f"{path}: unknown file type '.step'"
    if case == "missing file":
        return [tmp_path / "nowhere.obj", "--surface", surface], f"{tmp_path / 'nowhere.obj'}: file not found"
    if case == "surface without faces":
        path = _write(tmp_path, "empty.obj", "v 0 0 0\nv 1 0 0\n")
        write_obj(hypar_network(count=3), tmp_path / "curves.obj")
        return [tmp_path / "curves.obj", "--surface", path], f"{path}: no mesh faces found"
    if case == "mixed units: JSON":
        path = tmp_path / "m.network.json"
        save_network(hypar_network(count=3), path)
        return [path, "--units", "mm"], f"mixed units: {path} declares m but --units mm was given"
    if case == "zero tolerance":
        write_obj(hypar_network(count=3), tmp_path / "curves.obj")
        return [tmp_path / "curves.obj", "--surface", surface, "--tolerance", "0"], \
            "--tolerance 0.0: must be a positive number of millimetres"
    if case == "normals not perpendicular to the curves":
        network = hypar_network(count=3)
        network.lamellas[1].normals[:] = network.lamellas[1].curve[1] - network.lamellas[1].curve[0]  # along the curve
        network.lamellas[1].normals /= np.linalg.norm(network.lamellas[1].normals, axis=1)[:, None]
        path = tmp_path / "tilted.network.json"
        _write(tmp_path, path.name, json.dumps(network_to_dict(network)))
        return [path], f"{path}: lamella {network.lamellas[1].id}: normal 0 is not perpendicular to the curve"
    if case == "malformed JSON":
        path = _write(tmp_path, "m.json", '{\n "schema": "fabline.network/1",\n "units": "m",,\n}\n')
        return [path], f"{path}:3:"
    raise AssertionError(case)


CASES = ["malformed OBJ vertex", "malformed OBJ reference", "malformed DXF", "NaN coordinate", "zero-length curve",
         "self-overlapping curve", "curves that never cross", "a lamella that crosses nothing", "only one family",
         "duplicate lamella id", "four lamellas at one point", "a curve drawn twice", "missing normals", "mixed units: declared",
         "mixed units: surface scale", "mixed units: DXF surface", "unknown file type", "missing file",
         "surface without faces", "mixed units: JSON", "zero tolerance", "malformed JSON",
         "normals not perpendicular to the curves"]


@pytest.mark.parametrize("case", CASES)
def test_bad_input_is_named_on_one_line_with_exit_2_and_nothing_written(cli, tmp_path, surface, case):
    args, expected = bad_input(case, tmp_path, surface)
    out = tmp_path / "out" / "model.network.json"
    before = sorted(tmp_path.rglob("*"))
    code, stdout, stderr = cli("import", *args, "-o", out)
    assert code == 2 and stdout == "", stderr
    assert stderr.startswith("fabline import: error: ") and stderr.count("\n") == 1, stderr
    assert expected in stderr, stderr
    assert not out.exists() and sorted(tmp_path.rglob("*")) == before


def test_a_garbage_stl_is_named_without_the_missing_text_decoder(cli, tmp_path, monkeypatch):
    """trimesh guesses a broken STL's text encoding with an optional module; where it is missing the error still
    says what is wrong with the file, not "No module named 'charset_normalizer'"."""
    import sys

    for module in ("charset_normalizer", "chardet"):
        monkeypatch.setitem(sys.modules, module, None)  # as if not installed
    curves = _write(tmp_path, "curves.obj", obj_text(CROSS))
    surface = tmp_path / "garbage.stl"
    surface.write_bytes(bytes(range(256)) * 10)
    code, _, err = cli("import", curves, "--surface", surface, "-o", tmp_path / "out.json")
    assert code == 2 and err == (f"fabline import: error: {surface}: cannot read as a mesh: neither a binary nor "
                                 "a text mesh file\n"), err
    assert not (tmp_path / "out.json").exists()
