"""The data set format vdm-aero-dataset/1: round trips, third-party files, and every malformed case."""

from __future__ import annotations

import dataclasses
import tracemalloc
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from vdm_aero import dataset as dataset_module
from vdm_aero.coefficients import force_moment_matrix
from vdm_aero.dataset import (
    FORMAT,
    Case,
    Dataset,
    Reference,
    create_dataset_memmap,
    default_point_names,
    load_dataset,
    validate_dataset,
    write_dataset,
)
from vdm_aero.errors import DatasetError, UserInputError

M, N = 10, 6


def unit_rows(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def make_dataset(rng: np.random.Generator, *, m: int = M, n: int = N, cp_dtype: Any = np.float32) -> Dataset:
    """A small valid data set: two cases (ids 3 and 5), rows 0..m//2-1 belong to case 3."""
    case = np.where(np.arange(m) < m // 2, 3, 5).astype(np.int64)
    return Dataset(
        name="unit-test",
        source="synthetic: tests/test_dataset.py",
        reference=Reference(area_m2=0.5, chord_m=0.25, span_m=2.0),
        cases=(
            Case(3, "pitch-1hz", {"freq_hz": 1.0, "alpha0_deg": 4.0, "amplitude_deg": 6.0, "speed_m_s": 15}),
            Case(5, "static", {"speed_m_s": 12.0, "note": "kept verbatim", "tags": ["a", "b"]}),
        ),
        cp=rng.normal(size=(m, n)).astype(cp_dtype),
        points=rng.normal(size=(n, 3)),
        normals=unit_rows(rng, n),
        areas=rng.uniform(0.01, 0.1, n),
        alpha=rng.uniform(-0.2, 0.2, m),
        t=np.tile(np.linspace(0.0, 1.0, m // 2), 2),
        case=case,
        coeffs=rng.normal(size=(m, 6)),
        beta=rng.uniform(-0.1, 0.1, m),
        point_names=tuple(f"port-{i}" for i in range(n)),
        extra={"campaign": {"tunnel": "T1", "runs": [1, 2]}, "notes": "kept"},
    )


def write_by_hand(
    root: Path,
    rng: np.random.Generator,
    *,
    doc_edit: Callable[[dict[str, Any]], None] | None = None,
    arrays_edit: Callable[[dict[str, np.ndarray]], None] | None = None,
) -> Path:
    """Write a data set with plain numpy + yaml, the way a third party would (int32, float32, no coeffs)."""
    root.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, np.ndarray] = {
        "cp": rng.normal(size=(M, N)),
        "points": rng.normal(size=(N, 3)).astype(np.float32),
        "normals": unit_rows(rng, N),
        "areas": rng.uniform(0.01, 0.1, N),
        "alpha": rng.uniform(-0.2, 0.2, M).astype(np.float32),
        "t": np.linspace(0.0, 0.9, M),
        "case": np.array([0] * 5 + [1] * 5, dtype=np.int32),
    }
    doc: dict[str, Any] = {
        "format": FORMAT,
        "name": "by-hand",
        "source": "written with numpy and yaml",
        "reference": {"area_m2": 1.0, "chord_m": 0.5, "span_m": 2.0},
        "cases": [{"id": 0, "name": "a", "freq_hz": 2.0, "rig": "x"}, {"id": 1, "name": "b"}],
        "operator": "someone",
    }
    if doc_edit is not None:
        doc_edit(doc)
    if arrays_edit is not None:
        arrays_edit(arrays)
    (root / "dataset.yaml").write_text(yaml.safe_dump(doc))
    for name, arr in arrays.items():
        np.save(root / f"{name}.npy", arr)
    return root


# --------------------------------------------------------------------------------------------------
# Round trips
# --------------------------------------------------------------------------------------------------


def test_round_trip_preserves_everything(tmp_path: Path) -> None:
    ds = make_dataset(np.random.default_rng(0))
    out = write_dataset(tmp_path / "ds", ds)
    assert out == tmp_path / "ds"
    back = load_dataset(out)
    assert back.path == out
    assert isinstance(back.cp, np.memmap)
    assert back.cp.dtype == np.float32
    assert not back.cp.flags.writeable
    np.testing.assert_array_equal(back.cp, ds.cp)
    for key in ("points", "normals", "areas", "alpha", "t", "case", "coeffs", "beta"):
        np.testing.assert_array_equal(getattr(back, key), getattr(ds, key))
        assert getattr(back, key).dtype == (np.int64 if key == "case" else np.float64)
    assert back.name == ds.name
    assert back.source == ds.source
    assert back.reference == ds.reference
    assert back.cases == ds.cases
    assert back.cases[1].meta["tags"] == ["a", "b"]
    assert back.point_names == ds.point_names
    assert back.extra == ds.extra
    assert back.n_snapshots == M
    assert back.n_points == N
    # only the data set itself is left in the parent: the temp directory was renamed into place
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_round_trip_float64_cp_and_no_mmap(tmp_path: Path) -> None:
    ds = make_dataset(np.random.default_rng(1), cp_dtype=np.float64)
    back = load_dataset(write_dataset(tmp_path / "ds", ds), mmap=False)
    assert back.cp.dtype == np.float64
    assert not isinstance(back.cp, np.memmap)
    np.testing.assert_array_equal(back.cp, ds.cp)


def test_yaml_is_readable_and_in_format_order(tmp_path: Path) -> None:
    ds = make_dataset(np.random.default_rng(2))
    write_dataset(tmp_path / "ds", ds)
    text = (tmp_path / "ds" / "dataset.yaml").read_text()
    doc = yaml.safe_load(text)
    assert list(doc)[:6] == ["format", "name", "source", "reference", "cases", "point_names"]
    assert doc["format"] == FORMAT
    assert doc["cases"][0] == {
        "id": 3,
        "name": "pitch-1hz",
        "freq_hz": 1.0,
        "alpha0_deg": 4.0,
        "amplitude_deg": 6.0,
        "speed_m_s": 15,
    }
    assert "{" not in text.split("cases:")[1]  # block style, not flow style


def test_default_point_names_are_not_written(tmp_path: Path) -> None:
    ds = dataclasses.replace(make_dataset(np.random.default_rng(3)), point_names=())
    assert ds.point_names == ("p0000", "p0001", "p0002", "p0003", "p0004", "p0005")
    write_dataset(tmp_path / "ds", ds)
    assert "point_names" not in yaml.safe_load((tmp_path / "ds" / "dataset.yaml").read_text())
    assert load_dataset(tmp_path / "ds").point_names == ds.point_names


def test_default_point_names_widen_past_four_digits() -> None:
    names = default_point_names(12345)
    assert names[0] == "p00000"
    assert names[-1] == "p12344"
    assert default_point_names(3) == ("p0000", "p0001", "p0002")


def test_third_party_data_set_loads(tmp_path: Path) -> None:
    root = write_by_hand(tmp_path / "hand", np.random.default_rng(4))
    ds = load_dataset(root)
    assert ds.case.dtype == np.int64
    assert ds.alpha.dtype == np.float64
    assert ds.points.dtype == np.float64
    assert ds.cp.dtype == np.float64
    assert ds.coeffs is None
    assert ds.beta is None
    assert ds.extra == {"operator": "someone"}
    assert ds.cases[0].meta == {"freq_hz": 2.0, "rig": "x"}
    assert ds.cases[0].freq_hz == 2.0
    assert ds.cases[1].freq_hz is None
    assert ds.point_names[0] == "p0000"
    # without coeffs.npy the pressure integral is the truth
    np.testing.assert_allclose(ds.truth_coeffs(), ds.pressure_coeffs())


def test_yaml_1_1_exponent_strings_are_accepted_as_numbers(tmp_path: Path) -> None:
    def edit(doc: dict[str, Any]) -> None:
        doc["reference"]["area_m2"] = "1e-3"  # what PyYAML makes of `area_m2: 1e-3`

    ds = load_dataset(write_by_hand(tmp_path / "d", np.random.default_rng(5), doc_edit=edit))
    assert ds.reference.area_m2 == pytest.approx(1e-3)


def test_overwrites_existing_data_set_including_its_own_memmap_source(tmp_path: Path) -> None:
    path = write_dataset(tmp_path / "ds", make_dataset(np.random.default_rng(6)))
    ds = load_dataset(path)
    sub = ds.select_cases([5])
    write_dataset(path, sub)  # reads ds.cp's memory map while replacing the directory it maps
    back = load_dataset(path)
    assert back.case_ids() == (5,)
    np.testing.assert_array_equal(back.cp, sub.cp)
    assert [p.name for p in tmp_path.iterdir()] == ["ds"]


def test_write_into_empty_directory(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    write_dataset(tmp_path / "empty", make_dataset(np.random.default_rng(7)))
    assert load_dataset(tmp_path / "empty").n_snapshots == M


def test_write_creates_parent_directories(tmp_path: Path) -> None:
    path = write_dataset(tmp_path / "a" / "b" / "ds", make_dataset(np.random.default_rng(8)))
    assert (path / "dataset.yaml").is_file()


def test_write_refuses_foreign_directory(tmp_path: Path) -> None:
    foreign = tmp_path / "photos"
    foreign.mkdir()
    (foreign / "holiday.jpg").write_bytes(b"\xff\xd8")
    with pytest.raises(DatasetError, match="refusing to overwrite") as err:
        write_dataset(foreign, make_dataset(np.random.default_rng(9)))
    assert str(foreign) in str(err.value)
    assert (foreign / "holiday.jpg").read_bytes() == b"\xff\xd8"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]


def test_write_refuses_other_format_and_plain_file(tmp_path: Path) -> None:
    other = tmp_path / "other"
    other.mkdir()
    (other / "dataset.yaml").write_text("format: vdm-aero-dataset/2\n")
    with pytest.raises(DatasetError, match="not a vdm-aero-dataset/1 data set"):
        write_dataset(other, make_dataset(np.random.default_rng(10)))
    (tmp_path / "file").write_text("x")
    with pytest.raises(DatasetError, match="not a directory"):
        write_dataset(tmp_path / "file", make_dataset(np.random.default_rng(10)))


def test_write_validates_before_touching_disk(tmp_path: Path) -> None:
    ds = make_dataset(np.random.default_rng(11))
    bad = dataclasses.replace(ds, areas=-ds.areas)
    with pytest.raises(DatasetError, match=r"^areas\.npy: 6 negative areas"):
        write_dataset(tmp_path / "ds", bad)
    assert list(tmp_path.iterdir()) == []


def test_write_from_field_mapping(tmp_path: Path) -> None:
    ds = make_dataset(np.random.default_rng(12))
    fields = {f.name: getattr(ds, f.name) for f in dataclasses.fields(ds)}
    fields["reference"] = {"area_m2": 0.5, "chord_m": 0.25, "span_m": 2.0}
    fields["cases"] = [c.to_dict() for c in ds.cases]
    back = load_dataset(write_dataset(tmp_path / "ds", fields))
    assert back.reference == ds.reference
    assert back.cases == ds.cases
    with pytest.raises(DatasetError, match="missing data set field 'cp'"):
        write_dataset(tmp_path / "x", {k: v for k, v in fields.items() if k != "cp"})


def test_write_reports_unserialisable_metadata(tmp_path: Path) -> None:
    ds = dataclasses.replace(make_dataset(np.random.default_rng(13)), extra={"obj": object()})
    with pytest.raises(DatasetError, match="cannot be written as YAML"):
        write_dataset(tmp_path / "ds", ds)
    assert list(tmp_path.iterdir()) == []


def test_numpy_scalars_in_metadata_are_written_as_plain_yaml(tmp_path: Path) -> None:
    ds = make_dataset(np.random.default_rng(14))
    ds = dataclasses.replace(
        ds,
        cases=(Case(3, "a", {"freq_hz": np.float64(2.5)}), Case(5, "b")),
        extra={"gain": np.float32(0.5), "shape": (1, 2)},
    )
    back = load_dataset(write_dataset(tmp_path / "ds", ds))
    assert back.cases[0].freq_hz == 2.5
    assert back.extra == {"gain": 0.5, "shape": [1, 2]}


# --------------------------------------------------------------------------------------------------
# Malformed data sets
# --------------------------------------------------------------------------------------------------


def _set(key: str, value: Any) -> Callable[[dict[str, Any]], None]:
    def edit(doc: dict[str, Any]) -> None:
        doc[key] = value

    return edit


def _del_ref(key: str) -> Callable[[dict[str, Any]], None]:
    def edit(doc: dict[str, Any]) -> None:
        del doc["reference"][key]

    return edit


def _arr(name: str, fn: Callable[[np.ndarray], np.ndarray]) -> Callable[[dict[str, np.ndarray]], None]:
    def edit(arrays: dict[str, np.ndarray]) -> None:
        arrays[name] = fn(arrays[name])

    return edit


def _nan_at(*idx: int) -> Callable[[np.ndarray], np.ndarray]:
    def fn(a: np.ndarray) -> np.ndarray:
        a = a.copy()
        for i in idx:
            a[i] = np.nan if i % 2 else np.inf
        return a

    return fn


def _shrink_normal(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[4] *= 0.8
    a[1] *= 1.1
    a[2] *= 1.0 + 1e-3
    return a


def _cp_nan(a: np.ndarray) -> np.ndarray:
    a = a.copy()
    a[7, 2] = np.nan
    return a


DOC_CASES: list[tuple[str, Callable[[dict[str, Any]], None], str, str]] = [
    (
        "format-2",
        _set("format", "vdm-aero-dataset/2"),
        "dataset.yaml",
        "format 'vdm-aero-dataset/2' is not supported (expected vdm-aero-dataset/1)",
    ),
    ("no-format", lambda d: d.pop("format"), "dataset.yaml", "missing required key format"),
    ("no-name", lambda d: d.pop("name"), "dataset.yaml", "missing required key name"),
    ("no-cases", lambda d: d.pop("cases"), "dataset.yaml", "missing required key cases"),
    ("no-area", _del_ref("area_m2"), "dataset.yaml", "missing required key reference.area_m2"),
    (
        "zero-area",
        lambda d: d["reference"].update(area_m2=0.0),
        "dataset.yaml",
        "reference.area_m2 must be a positive finite number, got 0.0",
    ),
    (
        "negative-span",
        lambda d: d["reference"].update(span_m=-2),
        "dataset.yaml",
        "reference.span_m must be a positive",
    ),
    (
        "text-chord",
        lambda d: d["reference"].update(chord_m="wide"),
        "dataset.yaml",
        "reference.chord_m must be a positive",
    ),
    (
        "unknown-reference-key",
        lambda d: d["reference"].update(area_m=1.0),
        "dataset.yaml",
        "unknown key reference.area_m",
    ),
    ("reference-list", _set("reference", [1, 2, 3]), "dataset.yaml", "reference must be a mapping"),
    (
        "duplicate-case",
        lambda d: d["cases"].append({"id": 1, "name": "again"}),
        "dataset.yaml",
        "duplicate case id 1 in cases",
    ),
    ("empty-cases", _set("cases", []), "dataset.yaml", "cases is empty"),
    ("cases-mapping", _set("cases", {"id": 0}), "dataset.yaml", "cases must be a list"),
    (
        "case-without-name",
        lambda d: d["cases"][1].pop("name"),
        "dataset.yaml",
        "cases[1]: missing required key name",
    ),
    (
        "case-bool-id",
        lambda d: d["cases"][0].update(id=True),
        "dataset.yaml",
        "cases[0].id must be an integer",
    ),
    (
        "case-text-freq",
        lambda d: d["cases"][0].update(freq_hz="fast"),
        "dataset.yaml",
        "cases[0].freq_hz must be a number",
    ),
    (
        "point-names-short",
        _set("point_names", ["a", "b"]),
        "dataset.yaml",
        "point_names has 2 entries, expected N = 6 to match points.npy",
    ),
    (
        "point-names-duplicate",
        _set("point_names", ["a", "b", "c", "b", "e", "f"]),
        "dataset.yaml",
        "duplicate point name 'b' in point_names (indices 1 and 3)",
    ),
    (
        "point-names-not-text",
        _set("point_names", ["a", "b", 3, "d", "e", "f"]),
        "dataset.yaml",
        "point_names[2] must be a non-empty string",
    ),
    ("empty-name", _set("name", ""), "dataset.yaml", "name must be a non-empty string"),
    ("source-list", _set("source", ["a"]), "dataset.yaml", "source must be a string"),
]

ARRAY_CASES: list[tuple[str, Callable[[dict[str, np.ndarray]], None], str, str]] = [
    (
        "cp-wrong-n",
        _arr("cp", lambda a: a[:, :5]),
        "cp.npy",
        "shape (10, 5), expected (M, N) = (10, 6) to match points.npy",
    ),
    ("cp-1d", _arr("cp", lambda a: a[0]), "cp.npy", "1-D array with shape (6,), expected 2-D (M, N)"),
    ("cp-int", _arr("cp", lambda a: a.astype(np.int64)), "cp.npy", "dtype int64, expected a floating-point"),
    ("cp-no-rows", _arr("cp", lambda a: a[:0]), "cp.npy", "no snapshots"),
    ("cp-nan", _arr("cp", _cp_nan), "cp.npy", "1 NaN/Inf value (first at index (7, 2))"),
    ("points-2col", _arr("points", lambda a: a[:, :2]), "points.npy", "expected (N, 3)"),
    ("normals-short", _arr("normals", lambda a: a[:5]), "normals.npy", "expected (N, 3) = (6, 3)"),
    (
        "normals-not-unit",
        _arr("normals", _shrink_normal),
        "normals.npy",
        "3 normals are not unit length (worst |n| = 0.8 at index 4)",
    ),
    (
        "areas-2d",
        _arr("areas", lambda a: a[:, None]),
        "areas.npy",
        "2-D array with shape (6, 1), expected 1-D",
    ),
    (
        "areas-negative",
        _arr("areas", lambda a: np.where(np.arange(6) >= 4, -a, a)),
        "areas.npy",
        "2 negative areas (first at index 4",
    ),
    ("alpha-nan", _arr("alpha", _nan_at(3, 5)), "alpha.npy", "2 NaN/Inf values (first at index 3)"),
    (
        "alpha-short",
        _arr("alpha", lambda a: a[:9]),
        "alpha.npy",
        "shape (9,), expected (M,) = (10,) to match cp.npy",
    ),
    ("alpha-int", _arr("alpha", lambda a: np.zeros(10, np.int32)), "alpha.npy", "dtype int32"),
    ("t-long", _arr("t", lambda a: np.zeros(11)), "t.npy", "to match cp.npy"),
    (
        "case-unlisted",
        _arr("case", lambda a: np.where(np.arange(10) == 8, 7, a)),
        "case.npy",
        "case id 7 is not listed in dataset.yaml cases (first at index 8)",
    ),
    (
        "case-two-unlisted",
        _arr("case", lambda a: np.where(np.arange(10) >= 8, np.arange(10), a)),
        "case.npy",
        "case ids 8, 9 are not listed in dataset.yaml cases",
    ),
    ("case-float", _arr("case", lambda a: a.astype(np.float64)), "case.npy", "expected an integer array"),
    ("case-bool", _arr("case", lambda a: a.astype(bool)), "case.npy", "dtype bool, expected an integer"),
]


def _add_coeffs(shape: tuple[int, ...]) -> Callable[[dict[str, np.ndarray]], None]:
    def edit(arrays: dict[str, np.ndarray]) -> None:
        arrays["coeffs"] = np.zeros(shape)

    return edit


def _add_beta(arr: np.ndarray) -> Callable[[dict[str, np.ndarray]], None]:
    def edit(arrays: dict[str, np.ndarray]) -> None:
        arrays["beta"] = arr

    return edit


ARRAY_CASES += [
    ("coeffs-4col", _add_coeffs((10, 4)), "coeffs.npy", "expected (M, 3) or (M, 6) with M = 10"),
    ("coeffs-1d", _add_coeffs((10,)), "coeffs.npy", "expected 2-D"),
    ("beta-short", _add_beta(np.zeros(3)), "beta.npy", "expected (M,) = (10,)"),
    ("beta-inf", _add_beta(np.full(10, np.inf)), "beta.npy", "10 NaN/Inf values (first at index 0)"),
]


def _assert_one_line(err: pytest.ExceptionInfo[DatasetError], file: Path, phrase: str) -> None:
    msg = str(err.value)
    assert "\n" not in msg
    assert msg.startswith(f"{file}: "), msg
    assert phrase in msg, msg


@pytest.mark.parametrize(("label", "edit", "file", "phrase"), DOC_CASES, ids=[c[0] for c in DOC_CASES])
def test_malformed_yaml_is_reported(
    tmp_path: Path, label: str, edit: Callable[[dict[str, Any]], None], file: str, phrase: str
) -> None:
    root = write_by_hand(tmp_path / label, np.random.default_rng(20), doc_edit=edit)
    with pytest.raises(DatasetError) as err:
        load_dataset(root)
    _assert_one_line(err, root / file, phrase)


@pytest.mark.parametrize(("label", "edit", "file", "phrase"), ARRAY_CASES, ids=[c[0] for c in ARRAY_CASES])
def test_malformed_arrays_are_reported(
    tmp_path: Path, label: str, edit: Callable[[dict[str, np.ndarray]], None], file: str, phrase: str
) -> None:
    root = write_by_hand(tmp_path / label, np.random.default_rng(21), arrays_edit=edit)
    with pytest.raises(DatasetError) as err:
        load_dataset(root)
    _assert_one_line(err, root / file, phrase)


def test_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(DatasetError) as err:
        load_dataset(tmp_path / "nowhere")
    _assert_one_line(err, tmp_path / "nowhere", "data set directory does not exist")


def test_path_is_a_file(tmp_path: Path) -> None:
    (tmp_path / "f").write_text("x")
    with pytest.raises(DatasetError) as err:
        load_dataset(tmp_path / "f")
    _assert_one_line(err, tmp_path / "f", "not a directory")


@pytest.mark.parametrize("name", ["dataset.yaml", "cp.npy", "case.npy", "t.npy"])
def test_missing_required_file(tmp_path: Path, name: str) -> None:
    root = write_by_hand(tmp_path / "d", np.random.default_rng(22))
    (root / name).unlink()
    with pytest.raises(DatasetError) as err:
        load_dataset(root)
    _assert_one_line(err, root / name, "missing required file")


@pytest.mark.parametrize("mmap", [True, False])
@pytest.mark.parametrize("name", ["cp.npy", "points.npy", "beta.npy"])
def test_unreadable_npy(tmp_path: Path, name: str, mmap: bool) -> None:
    root = write_by_hand(tmp_path / "d", np.random.default_rng(23))
    (root / name).write_bytes(b"this is not an npy file at all")
    with pytest.raises(DatasetError) as err:
        load_dataset(root, mmap=mmap)
    _assert_one_line(err, root / name, "not a readable .npy file")


def test_truncated_npy(tmp_path: Path) -> None:
    root = write_by_hand(tmp_path / "d", np.random.default_rng(24))
    data = (root / "cp.npy").read_bytes()
    (root / "cp.npy").write_bytes(data[: len(data) // 2])
    with pytest.raises(DatasetError) as err:
        load_dataset(root)
    _assert_one_line(err, root / "cp.npy", "not a readable .npy file")


def test_pickled_object_array_is_refused(tmp_path: Path) -> None:
    root = write_by_hand(tmp_path / "d", np.random.default_rng(25))
    np.save(root / "areas.npy", np.array([{"a": 1}] * N, dtype=object), allow_pickle=True)
    with pytest.raises(DatasetError) as err:
        load_dataset(root)
    _assert_one_line(err, root / "areas.npy", "not a readable .npy file")


@pytest.mark.parametrize(
    ("text", "phrase"),
    [
        ("format: [unclosed\n", "YAML syntax error at line 2"),
        ("format: a\n  bad: indent\n", "YAML syntax error at line 2"),
        ("", "file is empty"),
        ("- just\n- a list\n", "top level must be a mapping, got list"),
        ("1: 2\nformat: vdm-aero-dataset/1\n", "top-level key 1 is not a string"),
    ],
)
def test_bad_yaml_text(tmp_path: Path, text: str, phrase: str) -> None:
    root = write_by_hand(tmp_path / "d", np.random.default_rng(26))
    (root / "dataset.yaml").write_text(text)
    with pytest.raises(DatasetError) as err:
        load_dataset(root)
    _assert_one_line(err, root / "dataset.yaml", phrase)


def test_dataset_error_is_a_user_input_error() -> None:
    assert issubclass(DatasetError, UserInputError)


def test_check_values_false_skips_only_the_cp_scan(tmp_path: Path) -> None:
    root = write_by_hand(tmp_path / "d", np.random.default_rng(27), arrays_edit=_arr("cp", _cp_nan))
    assert np.isnan(load_dataset(root, check_values=False).cp[7, 2])
    np.save(root / "alpha.npy", np.full(M, np.nan))
    with pytest.raises(DatasetError, match=r"alpha\.npy: 10 NaN/Inf values"):
        load_dataset(root, check_values=False)


# --------------------------------------------------------------------------------------------------
# In-memory validation
# --------------------------------------------------------------------------------------------------


def test_validate_in_memory_names_bare_files() -> None:
    ds = make_dataset(np.random.default_rng(30))
    validate_dataset(ds)  # valid: no exception
    bad = dataclasses.replace(ds, normals=ds.normals * 2.0)
    with pytest.raises(DatasetError, match=r"^normals\.npy: 6 normals are not unit length \(worst \|n\| = 2"):
        validate_dataset(bad)
    with pytest.raises(DatasetError, match=r"^dataset\.yaml: duplicate case id 3"):
        validate_dataset(dataclasses.replace(ds, cases=(Case(3, "a"), Case(3, "b"))))
    with pytest.raises(DatasetError, match=r"^dataset\.yaml: extra key 'cases' clashes"):
        validate_dataset(dataclasses.replace(ds, extra={"cases": 1}))
    with pytest.raises(DatasetError, match=r"^dataset\.yaml: cases\[0\] meta must not contain 'id'"):
        validate_dataset(dataclasses.replace(ds, cases=(Case(3, "a", {"id": 4}), Case(5, "b"))))
    with pytest.raises(DatasetError, match=r"^dataset\.yaml: reference\.chord_m must be a positive"):
        validate_dataset(dataclasses.replace(ds, reference=Reference(1.0, float("nan"), 1.0)))


def test_validate_uses_path_of_loaded_data_set(tmp_path: Path) -> None:
    ds = load_dataset(write_dataset(tmp_path / "ds", make_dataset(np.random.default_rng(31))))
    with pytest.raises(DatasetError) as err:
        validate_dataset(dataclasses.replace(ds, t=ds.t[:3]))
    _assert_one_line(err, tmp_path / "ds" / "t.npy", "expected (M,) = (10,)")


def test_normal_tolerance_is_1e_6() -> None:
    ds = make_dataset(np.random.default_rng(32))
    validate_dataset(dataclasses.replace(ds, normals=ds.normals * (1.0 + 5e-7)))
    with pytest.raises(DatasetError, match="not unit length"):
        validate_dataset(dataclasses.replace(ds, normals=ds.normals * (1.0 + 2e-6)))


def test_construction_upcasts_small_arrays_but_keeps_cp_dtype() -> None:
    ds = make_dataset(np.random.default_rng(33))
    ds2 = dataclasses.replace(ds, alpha=ds.alpha.astype(np.float32), case=ds.case.astype(np.int32))
    assert ds2.alpha.dtype == np.float64
    assert ds2.case.dtype == np.int64
    assert ds2.cp.dtype == np.float32
    validate_dataset(ds2)


# --------------------------------------------------------------------------------------------------
# Selection and coefficients
# --------------------------------------------------------------------------------------------------


def test_case_helpers_and_select_cases(tmp_path: Path) -> None:
    ds = load_dataset(write_dataset(tmp_path / "ds", make_dataset(np.random.default_rng(40))))
    assert ds.case_ids() == (3, 5)
    mask = ds.case_mask([5])
    np.testing.assert_array_equal(mask, np.arange(M) >= M // 2)
    sub = ds.select_cases([5])
    assert sub.case_ids() == (5,)
    assert sub.n_snapshots == M // 2
    assert sub.path is None
    assert isinstance(sub.cp, np.memmap)  # contiguous rows stay a view of the memory map
    np.testing.assert_array_equal(sub.cp, ds.cp[M // 2 :])
    assert sub.coeffs is not None
    assert ds.coeffs is not None
    np.testing.assert_array_equal(sub.coeffs, ds.coeffs[M // 2 :])
    validate_dataset(sub)
    both = ds.select_cases([5, 3])
    assert both.case_ids() == (3, 5)  # listed order is kept
    np.testing.assert_array_equal(both.cp, ds.cp)


def test_select_cases_with_interleaved_rows() -> None:
    ds = make_dataset(np.random.default_rng(41))
    ds = dataclasses.replace(ds, case=np.array([3, 5] * (M // 2)))
    sub = ds.select_cases([3])
    np.testing.assert_array_equal(sub.cp, ds.cp[::2])
    np.testing.assert_array_equal(sub.alpha, ds.alpha[::2])
    assert sub.beta is not None
    assert ds.beta is not None
    np.testing.assert_array_equal(sub.beta, ds.beta[::2])


def test_select_cases_rejects_unknown_and_empty() -> None:
    ds = make_dataset(np.random.default_rng(42))
    with pytest.raises(DatasetError, match=r"unknown case ids 4, 9 \(data set 'unit-test' has case ids 3, 5\)"):
        ds.select_cases([3, 9, 4])
    with pytest.raises(DatasetError, match="unknown case id 8"):
        ds.case_mask([8])
    with pytest.raises(DatasetError, match="no case ids selected"):
        ds.select_cases([])
    ds2 = dataclasses.replace(ds, cases=(*ds.cases, Case(9, "never-run")))
    with pytest.raises(DatasetError, match="selected case ids 9 have no snapshots"):
        ds2.select_cases([9])


def test_select_points() -> None:
    ds = make_dataset(np.random.default_rng(43))
    sub = ds.select_points([4, 1])
    assert sub.point_names == ("port-4", "port-1")
    np.testing.assert_array_equal(sub.cp, ds.cp[:, [4, 1]])
    np.testing.assert_array_equal(sub.points, ds.points[[4, 1]])
    np.testing.assert_array_equal(sub.normals, ds.normals[[4, 1]])
    np.testing.assert_array_equal(sub.areas, ds.areas[[4, 1]])
    assert sub.cp.dtype == np.float32
    validate_dataset(sub)
    by_mask = ds.select_points(np.arange(N) % 2 == 0)
    assert by_mask.point_names == ("port-0", "port-2", "port-4")
    np.testing.assert_array_equal(ds.point_indices(["port-5", "port-0"]), [5, 0])


def test_select_points_keeps_the_whole_vehicle_truth() -> None:
    ds = make_dataset(np.random.default_rng(46))
    assert ds.coeffs is not None
    for full in (ds, dataclasses.replace(ds, coeffs=None), dataclasses.replace(ds, coeffs=ds.coeffs[:, :3])):
        sub = full.select_points([0, 2])
        np.testing.assert_allclose(sub.truth_coeffs(), full.truth_coeffs())
        assert not np.allclose(sub.pressure_coeffs(), full.pressure_coeffs())


@pytest.mark.parametrize(
    ("idx", "phrase"),
    [
        ([0, 6], "point index 6 out of range for N = 6"),
        ([-1], "point index -1 out of range"),
        ([2, 2], "point index 2 selected twice"),
        ([], "no points selected"),
        ([True, False], "point mask has 2 entries, expected N = 6"),
        ([0.5], "point indices must be integers"),
        ([[0, 1]], "must be 1-D"),
    ],
)
def test_select_points_rejects_bad_indices(idx: Any, phrase: str) -> None:
    ds = make_dataset(np.random.default_rng(44))
    with pytest.raises(DatasetError, match=phrase.replace("(", r"\(")):
        ds.select_points(idx)


def test_point_indices_rejects_unknown_name() -> None:
    with pytest.raises(DatasetError, match="unknown point name 'nope'"):
        make_dataset(np.random.default_rng(45)).point_indices(["port-0", "nope"])


def test_force_matrix_and_pressure_coeffs() -> None:
    ds = make_dataset(np.random.default_rng(50))
    s = ds.force_matrix()
    np.testing.assert_array_equal(s, force_moment_matrix(ds.points, ds.normals, ds.areas, ds.reference))
    direct = ds.cp.astype(np.float64) @ s.T
    for chunk_rows in (None, 1, 3, 7, M, 1000):
        np.testing.assert_allclose(ds.pressure_coeffs(chunk_rows), direct, rtol=1e-12, atol=1e-14)
    with pytest.raises(ValueError, match="chunk_rows"):
        ds.pressure_coeffs(0)


def test_truth_coeffs_variants() -> None:
    ds = make_dataset(np.random.default_rng(51))
    assert ds.coeffs is not None
    np.testing.assert_array_equal(ds.truth_coeffs(), ds.coeffs)
    three = dataclasses.replace(ds, coeffs=ds.coeffs[:, :3])
    truth = three.truth_coeffs()
    assert truth.shape == (M, 6)
    np.testing.assert_array_equal(truth[:, :3], ds.coeffs[:, :3])
    np.testing.assert_allclose(truth[:, 3:], ds.pressure_coeffs()[:, 3:])
    none = dataclasses.replace(ds, coeffs=None)
    np.testing.assert_allclose(none.truth_coeffs(), ds.pressure_coeffs())


def test_case_properties() -> None:
    c = Case(1, "x", {"freq_hz": 2, "alpha0_deg": "1e-1", "speed_m_s": None, "other": "y"})
    assert c.freq_hz == 2.0
    assert isinstance(c.freq_hz, float)
    assert c.alpha0_deg == pytest.approx(0.1)
    assert c.amplitude_deg is None
    assert c.speed_m_s is None
    assert c.to_dict() == {
        "id": 1,
        "name": "x",
        "freq_hz": 2,
        "alpha0_deg": "1e-1",
        "speed_m_s": None,
        "other": "y",
    }


# --------------------------------------------------------------------------------------------------
# Bounded memory on a memory-mapped float32 cp
# --------------------------------------------------------------------------------------------------


def test_load_scan_and_pressure_coeffs_never_copy_all_of_cp(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    m, n = 400, 5000  # 8 MB of float32; a full float64 copy would be 16 MB
    # 20 rows a chunk (a few rows, as with 300000 points): the peak is about one float64 chunk, 0.8 MB
    monkeypatch.setattr(dataset_module, "CHUNK_ELEMENTS", 100_000)
    rng = np.random.default_rng(60)
    with create_dataset_memmap(tmp_path / "big", n_snapshots=m, n_points=n) as w:
        for start in range(0, m, 100):
            w.cp[start : start + 100] = rng.normal(size=(100, n))
        w.finish(
            name="big",
            reference={"area_m2": 1.0, "chord_m": 1.0, "span_m": 1.0},
            cases=[{"id": 0, "name": "all"}],
            points=rng.normal(size=(n, 3)),
            normals=unit_rows(rng, n),
            areas=np.full(n, 1e-3),
            alpha=np.zeros(m),
            t=np.arange(m) * 0.01,
            case=np.zeros(m, dtype=np.int64),
        )
    full_f32 = m * n * 4
    tracemalloc.start()
    try:
        ds = load_dataset(tmp_path / "big")
        _, peak_load = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        coeffs = ds.pressure_coeffs()
        _, peak_coeffs = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        coeffs_7 = ds.pressure_coeffs(chunk_rows=7)
        _, peak_coeffs_7 = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert isinstance(ds.cp, np.memmap)
    assert peak_load < full_f32 / 4
    assert peak_coeffs < full_f32 / 4
    assert peak_coeffs_7 < full_f32 / 4
    np.testing.assert_allclose(coeffs_7, coeffs, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(coeffs, np.asarray(ds.cp, dtype=np.float64) @ ds.force_matrix().T, rtol=1e-10)


# --------------------------------------------------------------------------------------------------
# create_dataset_memmap
# --------------------------------------------------------------------------------------------------


def _finish_kwargs(ds: Dataset) -> dict[str, Any]:
    return {
        "name": ds.name,
        "source": ds.source,
        "reference": ds.reference,
        "cases": ds.cases,
        "points": ds.points,
        "normals": ds.normals,
        "areas": ds.areas,
        "alpha": ds.alpha,
        "t": ds.t,
        "case": ds.case,
        "coeffs": ds.coeffs,
        "beta": ds.beta,
        "point_names": ds.point_names,
        "extra": ds.extra,
    }


def test_memmap_writer_round_trip(tmp_path: Path) -> None:
    ds = make_dataset(np.random.default_rng(70))
    dest = tmp_path / "mm"
    with create_dataset_memmap(dest, n_snapshots=M, n_points=N) as w:
        assert not dest.exists()  # nothing visible until finish
        row = 0
        for start in range(0, M, 3):
            row = w.write_rows(start, ds.cp[start : start + 3])
        assert row == M
        out = w.finish(**_finish_kwargs(ds))
    assert out == dest
    back = load_dataset(dest)
    assert back.cp.dtype == np.float32
    np.testing.assert_array_equal(back.cp, ds.cp)
    assert back.cases == ds.cases
    assert back.point_names == ds.point_names
    assert back.extra == ds.extra
    assert back.coeffs is not None
    assert ds.coeffs is not None
    np.testing.assert_array_equal(back.coeffs, ds.coeffs)
    assert [p.name for p in tmp_path.iterdir()] == ["mm"]
    with pytest.raises(RuntimeError, match="already finished"):
        _ = w.cp


def test_memmap_writer_float64_and_replace_existing(tmp_path: Path) -> None:
    dest = write_dataset(tmp_path / "mm", make_dataset(np.random.default_rng(71)))
    ds = make_dataset(np.random.default_rng(72), m=4, cp_dtype=np.float64)
    w = create_dataset_memmap(dest, n_snapshots=4, n_points=N, dtype=np.float64)
    w.cp[:] = ds.cp
    w.finish(**_finish_kwargs(ds))
    back = load_dataset(dest)
    assert back.cp.dtype == np.float64
    assert back.n_snapshots == 4
    np.testing.assert_array_equal(back.cp, ds.cp)
    assert [p.name for p in tmp_path.iterdir()] == ["mm"]


def test_memmap_writer_invalid_finish_installs_nothing_and_can_retry(tmp_path: Path) -> None:
    ds = make_dataset(np.random.default_rng(73))
    dest = tmp_path / "mm"
    with create_dataset_memmap(dest, n_snapshots=M, n_points=N) as w:
        w.cp[:] = ds.cp
        bad = _finish_kwargs(ds) | {"alpha": ds.alpha[:4]}
        with pytest.raises(DatasetError, match=r"^alpha\.npy: shape \(4,\), expected \(M,\) = \(10,\)"):
            w.finish(**bad)
        assert not dest.exists()
        w.finish(**_finish_kwargs(ds))
    assert load_dataset(dest).n_snapshots == M


def test_memmap_writer_abort_and_context_exit_clean_up(tmp_path: Path) -> None:
    w = create_dataset_memmap(tmp_path / "a", n_snapshots=2, n_points=3)
    assert len(list(tmp_path.iterdir())) == 1  # the temporary directory
    w.abort()
    assert list(tmp_path.iterdir()) == []

    def fill_then_fail() -> None:
        with create_dataset_memmap(tmp_path / "b", n_snapshots=2, n_points=3) as w2:
            w2.cp[0] = 1.0
            raise KeyError("caller failed")

    with pytest.raises(KeyError, match="caller failed"):
        fill_then_fail()
    assert list(tmp_path.iterdir()) == []


def test_memmap_writer_rejects_bad_arguments(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="sizes must be positive integers"):
        create_dataset_memmap(tmp_path / "a", n_snapshots=0, n_points=3)
    with pytest.raises(DatasetError, match="expected a floating-point dtype"):
        create_dataset_memmap(tmp_path / "a", n_snapshots=2, n_points=3, dtype=np.int32)
    (tmp_path / "foreign").mkdir()
    (tmp_path / "foreign" / "keep.txt").write_text("x")
    with pytest.raises(DatasetError, match="refusing to overwrite"):
        create_dataset_memmap(tmp_path / "foreign", n_snapshots=2, n_points=3)
    with create_dataset_memmap(tmp_path / "c", n_snapshots=2, n_points=3) as w:
        with pytest.raises(DatasetError, match="cannot write a block of shape"):
            w.write_rows(1, np.zeros((2, 3)))
        with pytest.raises(DatasetError, match="cannot write a block of shape"):
            w.write_rows(0, np.zeros((1, 4)))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["foreign"]


@pytest.mark.parametrize("order", ["C", "F"])
def test_read_columns_matches_the_whole_array_and_names_a_bad_file(tmp_path: Path, order: str) -> None:
    """The port columns read in row chunks equal the columns of the loaded array, whatever the chunk and the
    memory order; a truncated file or a column out of range is one error naming the file."""
    from vdm_aero.dataset import read_columns

    rng = np.random.default_rng(4)
    a = np.asarray(rng.normal(size=(37, 11)).astype(np.float32), order=order)
    path = tmp_path / "cp.npy"
    np.save(path, a)
    cols = np.array([10, 0, 3, 3])
    for chunk in (1, 5, 100):
        got = read_columns(path, cols, chunk_rows=chunk)
        assert got.dtype == np.float32 and np.array_equal(got, a[:, cols])
    with pytest.raises(DatasetError, match=r"cp\.npy: column 11 out of range"):
        read_columns(path, np.array([11]))
    path.write_bytes(path.read_bytes()[:-40])
    with pytest.raises(DatasetError, match=r"cp\.npy: truncated"):
        read_columns(path, cols)
