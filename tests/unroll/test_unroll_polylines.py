"""The lean in-memory forms behind the unroll's speed: `Polylines` against the list of arrays it stands for, the
pooled parts.json loader against the file (byte-identical round trip, one-line errors naming part and field),
the one-pass glyph placement against `layout` string by string, and the vectorised washer keys against the
per-node rounding they replace."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.unroll import (Part, PartSet, Polylines, UnrollOptions, load_parts, parts_to_dict, save_parts,
                            unroll_network)
from fabline.unroll.hardware import washer_keys
from fabline.unroll.strokes import characters, gather, layout


def random_polylines(rng, count, width=2):
    return [rng.normal(size=(int(rng.integers(2, 9)), width)) for _ in range(count)]


def test_polylines_read_as_the_list_they_stand_for():
    rng = np.random.default_rng(1)
    lines = random_polylines(rng, 7)
    lean = Polylines.of(lines)
    assert isinstance(lean, Polylines) and len(lean) == 7 and len(lean.points) == sum(len(x) for x in lines)
    assert all(np.array_equal(a, b) for a, b in zip(lean, lines))
    for k in range(-7, 7):
        assert np.array_equal(lean[k], lines[k])
    with pytest.raises(IndexError):
        lean[7]
    with pytest.raises(IndexError):
        lean[-8]
    assert [x.shape for x in lean[2:5]] == [x.shape for x in lines[2:5]]
    extra = [np.zeros((2, 2))]
    assert [x.shape for x in lean + extra] == [x.shape for x in lines + extra]
    assert [x.shape for x in extra + lean] == [x.shape for x in extra + lines]
    assert len(lean + lean) == 14 and not Polylines.of([]) and bool(lean)
    assert Polylines.of(lean) is lean
    mixed = Polylines.of([np.zeros((2, 2)), np.zeros((3, 3))])   # one array holds one width: stays a list
    assert isinstance(mixed, list) and [x.shape for x in mixed] == [(2, 2), (3, 3)]


def test_polylines_write_the_same_json_as_lists():
    rng = np.random.default_rng(2)
    outline = np.array([[0, 0], [10, 0], [10, 5], [0, 5], [0, 0]], dtype=float)
    text, marks = random_polylines(rng, 5), random_polylines(rng, 3, width=3)
    as_lists = PartSet([Part("P", "strip", outline, marks=marks, text=text)])
    lean = PartSet([Part("P", "strip", outline, marks=Polylines.of(marks), text=Polylines.of(text))])
    assert json.dumps(parts_to_dict(as_lists)) == json.dumps(parts_to_dict(lean))


def test_the_saved_file_holds_what_the_json_module_would_write(tmp_path):
    """save_parts writes numpy row views through orjson; the standard library reads back the very values its own
    encoder would have written from the list form (tiny values, exponents and numpy scalars included)."""
    rng = np.random.default_rng(5)
    outline = np.array([[0, 0], [10, 0], [10, 5], [0, 5], [0, 0]], dtype=float)
    outline[1:4] += rng.normal(scale=[1.0, 1e-4], size=(3, 2))
    text = Polylines.of(random_polylines(rng, 5) + [np.array([[1e-5, 0.00005], [2.00015, -0.00004]])])
    partset = PartSet([Part("P", "strip", outline, holes=random_polylines(rng, 2, width=3), text=text)],
                      report={"max_in_plane_curvature_per_m": 1e-6, "count": np.int64(3), "ratio": np.float64(0.25)})
    save_parts(partset, tmp_path / "parts.json")
    written = json.loads((tmp_path / "parts.json").read_text())
    as_lists = parts_to_dict(partset)
    as_lists["report"] = {"max_in_plane_curvature_per_m": 1e-6, "count": 3, "ratio": 0.25}
    assert written == json.loads(json.dumps(as_lists))


def test_a_non_finite_coordinate_is_refused_and_nothing_is_written(tmp_path):
    outline = np.array([[0, 0], [10, 0], [10, np.nan], [0, 5], [0, 0]], dtype=float)
    with pytest.raises(ValueError, match="NaN or infinite"):
        save_parts(PartSet([Part("P", "strip", outline)]), tmp_path / "parts.json")
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def pavilion_file(enneper, tmp_path_factory):
    path = tmp_path_factory.mktemp("parts") / "parts.json"
    save_parts(unroll_network(enneper, UnrollOptions()), path)
    return path


def test_loading_and_saving_again_gives_the_same_bytes(pavilion_file, tmp_path):
    partset = load_parts(pavilion_file)
    strips = [p for p in partset.parts if p.kind == "strip"]
    assert strips and all(isinstance(p.text, Polylines) and isinstance(p.marks, Polylines) for p in strips)
    again = tmp_path / "again.json"
    save_parts(partset, again)
    assert again.read_bytes() == pavilion_file.read_bytes()
    raw = json.loads(pavilion_file.read_text())["parts"]
    for part, data in zip(partset.parts[:40], raw[:40]):  # arrays equal to the file's lists, one by one
        assert [t.tolist() for t in part.text] == data["text"] and part.outline.tolist() == data["outline"]
        assert [h.tolist() for h in part.holes] == data["holes"]


def test_mixed_vertex_widths_in_one_field_load_as_a_list_and_round_trip(pavilion_file, tmp_path):
    data = json.loads(pavilion_file.read_text())
    strip = next(p for p in data["parts"] if p["kind"] == "strip")
    strip["text"][1] = [vertex + [0.5] for vertex in strip["text"][1]]   # a bulge column on one polyline
    path = tmp_path / "mixed.json"
    path.write_text(json.dumps(data, separators=(",", ":")))
    loaded = load_parts(path)
    part = next(p for p in loaded.parts if p.id == strip["id"])
    assert isinstance(part.text, list) and part.text[1].shape[1] == 3 and part.text[0].shape[1] == 2
    assert parts_to_dict(loaded)["parts"] == data["parts"]


@pytest.fixture(scope="module")
def small_data(pavilion_file):
    """The first strips and washers of the pavilion's parts.json: bad-input cases need no 8 MB file each."""
    data = json.loads(pavilion_file.read_text())
    data["parts"] = data["parts"][:12] + [p for p in data["parts"] if p["kind"] == "washer"][:3]
    return data


def broken(data, index, change):
    """A copy of the parts file data with part `index` changed by `change` (a function of the part dict)."""
    data = copy.deepcopy(data)
    change(data["parts"][index])
    return data


BAD_INPUTS = {
    "string vertex in text": (lambda p: p["text"][3].__setitem__(1, ["x", 2.0]), "text[3]: must be a list of"),
    "NaN in a hole": (lambda p: p["holes"][0][1].__setitem__(0, float("nan")), "holes[0]: contains NaN or infinite"),
    "open slot": (lambda p: p["slots"][0]["outline"].__setitem__(-1, [999.0, 999.0, 0.0]), "slots[0]: must be closed"),
    "one-vertex mark": (lambda p: p["marks"].__setitem__(2, [[0.0, 0.0]]), "marks[2]: must be a list of"),
    "four-column outline": (lambda p: p["outline"].__setitem__(1, [0.0, 0.0, 0.0, 0.0]), "outline: must be a list of"),
    "empty text polyline": (lambda p: p["text"].__setitem__(0, []), "text[0]: must be a list of"),
    "number as a contour": (lambda p: p["holes"].__setitem__(1, 5), "holes[1]: must be a list of"),
    "holes not a list": (lambda p: p.__setitem__("holes", {"a": 1}), "holes must be a list"),
    "slot not an object": (lambda p: p["slots"].__setitem__(1, [[0, 0], [1, 0], [1, 1], [0, 0]]),
                           "slots[1] must be an object"),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_bad_contours_are_named_by_part_and_field(case, small_data, tmp_path):
    data = small_data
    index = next(k for k, p in enumerate(data["parts"]) if p["kind"] == "strip" and k > 5
                 and min(len(p["slots"]), len(p["holes"]), len(p["marks"]) - 1, len(p["text"]) - 2) > 1)
    change, message = BAD_INPUTS[case]
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(broken(data, index, change)))
    with pytest.raises(FablineError) as error:
        load_parts(path)
    text = str(error.value)
    assert text == text.splitlines()[0] and f"part {data['parts'][index]['id']}: {message}" in text, text


def test_a_bad_parts_file_is_a_one_line_cli_error(small_data, tmp_path, cli):
    data = small_data
    path = tmp_path / "bad.json"
    path.write_text(json.dumps(broken(data, 3, lambda p: p["text"][0].__setitem__(0, [1.0, float("inf")]))))
    code, _, err = cli("nest", path, "-o", tmp_path / "nesting.json")
    assert code == 2 and "contains NaN or infinite values" in err and "Traceback" not in err
    assert not (tmp_path / "nesting.json").exists()


def test_one_pass_glyph_placement_equals_layout_string_by_string():
    texts = ["N104-007", "A-007-L.6 6/11 <A-007-L.5 A-007-L.7>", "J N12", "", "  x  ", "N104-007"]
    chars = characters(texts)
    rng = np.random.default_rng(4)
    which = rng.integers(0, len(texts), 40)
    scale, shift = rng.uniform(1.0, 8.0, len(which)), rng.normal(scale=500.0, size=(len(which), 2))
    char_of = [chars.first[w] + np.arange(chars.lengths[w]) for w in which]
    item = np.concatenate(char_of).astype(int)
    owner = np.repeat(np.arange(len(which)), chars.lengths[which])
    placed = gather(chars.table, chars.glyph[item], scale[owner], shift[owner], chars.advance[item])
    stroke_string = owner[placed.stroke_owner]
    bounds = np.append(placed.starts, len(placed.points))
    for k, w in enumerate(which):
        expected = layout(texts[w])
        assert chars.widths[w] == pytest.approx(expected.width, abs=1e-12)
        strokes = np.flatnonzero(stroke_string == k)
        got = [placed.points[bounds[s]:bounds[s + 1]] for s in strokes]
        want = np.split(expected.points * scale[k] + shift[k], expected.starts[1:]) if len(expected.points) else []
        assert len(got) == len(want)
        assert all(np.allclose(g, e, rtol=0.0, atol=1e-9) for g, e in zip(got, want)), texts[w]


def test_washer_keys_equal_the_per_node_rounding():
    rng = np.random.default_rng(6)
    counts = rng.choice([2, 2, 2, 3], 3000)
    angles = rng.uniform(-180.0, 180.0, counts.sum())
    angles[::7] = np.round(angles[::7] * 4.0) / 4.0     # exactly on quarter degrees: rounding ties
    bounds = np.append(0, np.cumsum(counts)).tolist()
    expected = []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        arms = angles[lo:hi].tolist()
        expected.append(tuple(sorted({round((a - arms[0]) % 180.0 * 2.0) / 2.0 % 180.0 for a in arms})))
    assert washer_keys(angles, bounds) == expected
