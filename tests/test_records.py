"""What a run writes: metric columns, metrics.csv, TensorBoard events and summary.json."""

import csv
import json
import struct

import numpy as np
import pytest
from tensorboardX.proto import event_pb2

from emgail_jax.host import records

NAN = float("nan")


def _metrics(first=0.0):
    """Two seeds, two iterations, K = 3: a scalar, a [K] metric, an int [K] and a NaN."""
    erd = np.array([[0.5, 0.25], [1.0, 0.125]]) + first
    returns = np.arange(12, dtype=np.float32).reshape(2, 2, 3) + first
    return {
        "eval/erd": erd,
        "eval/returns": returns,
        "eval/matching": np.array([[[2, 0, 1]] * 2] * 2, np.int32),
        "eval/cluster_accuracy": np.full((2, 2), np.nan),
    }


def test_flatten_metrics_gives_one_column_per_intention():
    columns = records.flatten_metrics(_metrics())
    assert list(columns) == [
        "eval/cluster_accuracy",
        "eval/erd",
        "eval/matching/0",
        "eval/matching/1",
        "eval/matching/2",
        "eval/returns/0",
        "eval/returns/1",
        "eval/returns/2",
    ]
    assert all(values.shape == (2, 2) for values in columns.values())
    # returns[s, l, k] = 6 s + 3 l + k.
    np.testing.assert_array_equal(columns["eval/returns/2"], [[2, 5], [8, 11]])
    np.testing.assert_array_equal(columns["eval/matching/0"], [[2, 2], [2, 2]])
    np.testing.assert_array_equal(columns["eval/erd"], _metrics()["eval/erd"])


def _read_csv(path):
    with open(path, newline="") as f:
        return list(csv.reader(f))


def test_metrics_log_writes_rows_iteration_major_with_nan_as_empty(tmp_path):
    log = records.MetricsLog(str(tmp_path), tensorboard=False)
    log.write(0, _metrics())
    log.write(2, _metrics(first=100.0))
    log.close()
    rows = _read_csv(tmp_path / "metrics.csv")
    header, body = rows[0], rows[1:]
    assert header[:4] == ["iteration", "seed", "eval/cluster_accuracy", "eval/erd"]
    assert header[-1] == "eval/returns/2"
    # One header only, then (iteration 1..4) x (seed 0, 1), iteration-major, 1-based.
    assert [(int(r[0]), int(r[1])) for r in body] == [(i, s) for i in (1, 2, 3, 4) for s in (0, 1)]
    table = [dict(zip(header, r, strict=True)) for r in body]
    assert all(r["eval/cluster_accuracy"] == "" for r in table)
    erd = [float(r["eval/erd"]) for r in table]
    # erd[seed, step]: seed 0 (0.5, 0.25), seed 1 (1.0, 0.125), then the same + 100.
    assert erd == [0.5, 1.0, 0.25, 0.125, 100.5, 101.0, 100.25, 100.125]
    assert [r["eval/returns/1"] for r in table[:4]] == ["1", "7", "4", "10"]
    assert table[0]["eval/matching/0"] == "2"
    assert not (tmp_path / "tensorboard").exists()


def test_metrics_log_names_seeds_as_the_run_numbers_them(tmp_path):
    """``run --seed 4 --seeds 2``: rows, TensorBoard folders and W&B keys say seeds 4 and 5."""
    logged = []
    wandb_run = type("Run", (), {"log": lambda self, row, step: logged.append(row)})()
    log = records.MetricsLog(str(tmp_path), first_seed=4, wandb_run=wandb_run)
    log.write(0, _metrics())
    log.close()
    body = _read_csv(tmp_path / "metrics.csv")[1:]
    assert [(int(r[0]), int(r[1])) for r in body] == [(1, 4), (1, 5), (2, 4), (2, 5)]
    assert sorted(p.name for p in (tmp_path / "tensorboard").iterdir()) == ["seed_4", "seed_5"]
    assert logged[0]["seed_5/eval/erd"] == 1.0 and not any("seed_0" in k for k in logged[0])


def test_metrics_log_rounds_to_six_significant_digits(tmp_path):
    log = records.MetricsLog(str(tmp_path), tensorboard=False)
    log.write(0, {"x": np.array([[1.0 / 3.0, 123456789.0, -0.0001234567, np.inf]])})
    rows = _read_csv(tmp_path / "metrics.csv")
    assert [r[2] for r in rows[1:]] == ["0.333333", "1.23457e+08", "-0.000123457", "inf"]


def _scalars(directory):
    """``{tag: [(step, value)]}`` from the TFRecord event files in ``directory``."""
    out = {}
    for path in sorted(directory.iterdir()):
        data = path.read_bytes()
        offset = 0
        while offset < len(data):
            (length,) = struct.unpack("<Q", data[offset : offset + 8])
            event = event_pb2.Event.FromString(data[offset + 12 : offset + 12 + length])
            offset += 12 + length + 4  # length, its CRC, the record, its CRC
            for value in event.summary.value:
                out.setdefault(value.tag, []).append((event.step, value.simple_value))
    return out


def test_metrics_log_writes_finite_scalars_to_tensorboard_per_seed(tmp_path):
    log = records.MetricsLog(str(tmp_path))
    log.write(0, _metrics())
    log.write(2, _metrics(first=100.0))
    log.close()
    board = tmp_path / "tensorboard"
    assert sorted(p.name for p in board.iterdir()) == ["seed_0", "seed_1"]
    seed1 = _scalars(board / "seed_1")
    assert seed1["eval/erd"] == [(1, 1.0), (2, 0.125), (3, 101.0), (4, 100.125)]
    assert [v for _, v in seed1["eval/returns/2"]] == [8.0, 11.0, 108.0, 111.0]
    # NaN (no accuracy) is left out rather than plotted.
    assert "eval/cluster_accuracy" not in seed1


def test_to_json_value_maps_nan_to_null_and_numpy_to_plain_types():
    value = records.to_json_value(
        {
            "erd": np.array([0.5, np.nan], np.float32),
            "accuracy": np.float32(np.nan),
            "count": np.int64(7),
            "returns": (np.float64(-1.5), float("nan")),
            "nested": {"ints": np.arange(3), "name": "driver", "none": None},
            "scalar": np.array(2.5),
        }
    )
    assert value == {
        "erd": [0.5, None],
        "accuracy": None,
        "count": 7,
        "returns": [-1.5, None],
        "nested": {"ints": [0, 1, 2], "name": "driver", "none": None},
        "scalar": 2.5,
    }
    assert type(value["count"]) is int and type(value["erd"][0]) is float
    assert type(value["nested"]["ints"][0]) is int
    # Strict JSON: no NaN token anywhere.
    json.dumps(value, allow_nan=False)


def test_to_json_value_converts_jax_arrays():
    import jax.numpy as jnp

    value = records.to_json_value({"price": jnp.array([-1.5, jnp.nan]), "one": jnp.int32(3)})
    assert value == {"price": [-1.5, None], "one": 3} and type(value["one"]) is int


def test_to_json_value_converts_numpy_booleans():
    value = records.to_json_value({"flag": np.bool_(True), "flags": np.array([True, False])})
    assert value == {"flag": True, "flags": [True, False]}
    json.dumps(value)


def _strict_load(path):
    def reject(token):
        raise ValueError(f"non-standard JSON token {token}")

    return json.loads(path.read_text(), parse_constant=reject)


def test_write_json_is_atomic_and_replaces_the_file(tmp_path):
    path = tmp_path / "summary.json"
    records.write_json(str(path), {"status": "running", "erd": np.float32(np.nan)})
    assert _strict_load(path) == {"status": "running", "erd": None}
    records.write_json(str(path), {"status": "completed", "erd": [np.float64(0.25)]})
    assert _strict_load(path) == {"status": "completed", "erd": [0.25]}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["summary.json"]
    assert path.read_text().endswith("}\n")


def test_write_json_keeps_a_list_of_numbers_on_one_line_and_reads_back_exactly(tmp_path):
    path = tmp_path / "check.json"
    curve = np.linspace(0.0, 1.0, 7) ** 3  # [iterations] float64, 17 digits
    data = {"erd_curve": curve, "per_seed": [{"curve": curve[:, None] * [1, 2]}], "empty": {}}
    records.write_json(str(path), data)
    lines = path.read_text().splitlines()
    assert lines[1] == f'  "erd_curve": {json.dumps(curve.tolist())},'
    assert sum(line.strip().startswith("[0.0, 0.0]") for line in lines) == 1  # one row a line
    assert _strict_load(path) == {
        "erd_curve": curve.tolist(),
        "per_seed": [{"curve": (curve[:, None] * [1, 2]).tolist()}],
        "empty": {},
    }


def test_write_json_failure_keeps_the_previous_file(tmp_path):
    path = tmp_path / "summary.json"
    records.write_json(str(path), {"status": "running"})
    with pytest.raises(TypeError):
        records.write_json(str(path), {"status": object()})
    assert _strict_load(path) == {"status": "running"}


def test_machine_facts_name_the_cpu_its_vector_extensions_and_the_packages(tmp_path):
    cpuinfo = tmp_path / "cpuinfo"
    cpuinfo.write_text(
        "processor\t: 0\nmodel name\t: Some CPU 9000\n"
        "flags\t\t: fpu sse2 sse4_2 avx2 fma avx512f ht\n\n"
        "processor\t: 1\nmodel name\t: Some CPU 9000\nflags\t\t: fpu\n"
    )
    facts = records.machine_facts(str(cpuinfo))
    assert facts["cpu"] == "Some CPU 9000"
    assert facts["cpu_features"] == ["avx2", "avx512f", "fma", "sse4_2"]  # codegen-relevant only
    assert facts["packages"]["jax"] == __import__("jax").__version__
    json.dumps(facts)  # fits summary.json as it is


def test_machine_facts_without_cpuinfo_still_name_the_machine(tmp_path):
    facts = records.machine_facts(str(tmp_path / "missing"))
    assert facts["cpu"] and facts["cpu_features"] == []


def test_continuing_a_log_drops_a_row_cut_short_and_the_rows_after_the_checkpoint(tmp_path):
    log = records.MetricsLog(str(tmp_path), tensorboard=False)
    log.write(0, _metrics())  # iterations 1-2
    log.write(2, _metrics(10.0))  # iterations 3-4, after the checkpoint of iteration 2
    path = tmp_path / "metrics.csv"
    kept = path.read_text().splitlines()[:5]  # the header and iterations 1-2 of both seeds
    with path.open("a") as f:
        f.write("1")  # killed while writing iteration 12's row: its number cut to "1"
    records.MetricsLog(str(tmp_path), tensorboard=False, keep_until=2)
    assert path.read_text().splitlines() == kept
    path.write_text(kept[0][:10])  # a header cut short: nothing to keep, the log starts afresh
    again = records.MetricsLog(str(tmp_path), tensorboard=False, keep_until=0)
    assert not path.exists()
    again.write(0, _metrics())
    assert path.read_text().splitlines() == kept


# A W&B offline run keeps everything in its transaction log, run-ID.wandb: a 7-byte header
# (":W&B", magic, version), then LevelDB-log blocks of 32 KiB holding records with a 7-byte
# header each (CRC-32, length, type: full, or first / middle / last parts of one record), each
# record a wandb_internal_pb2.Record. wandb has no reader of its own for it in Python.
_BLOCK, _HEADER, _FULL, _LAST = 32768, 7, 1, 4


def _wandb_records(path):
    from wandb.proto import wandb_internal_pb2

    data = path.read_bytes()
    assert data[:4] == b":W&B"
    position, pending = _HEADER, b""
    while position + _HEADER <= len(data):
        left = _BLOCK - position % _BLOCK
        if left < _HEADER:  # a block's tail too short for a record header is padding
            position += left
            continue
        _, length, kind = struct.unpack("<IHB", data[position : position + _HEADER])
        pending += data[position + _HEADER : position + _HEADER + length]
        position += _HEADER + length
        if kind in (_FULL, _LAST):
            record = wandb_internal_pb2.Record()
            record.ParseFromString(pending)
            pending = b""
            yield record


def _items(update):
    return {"/".join(item.nested_key) or item.key: json.loads(item.value_json) for item in update}


def _offline_run(wandb_dir):
    """``(project, history {step: {key: value}}, config, summary)`` of the one offline run
    there."""
    (path,) = wandb_dir.glob("wandb/offline-run-*/run-*.wandb")
    history, config, summary = {}, {}, {}
    for record in _wandb_records(path):
        kind = record.WhichOneof("record_type")
        if kind == "run":  # the config given to wandb.init
            config.update(_items(record.run.config.update))
            project = record.run.project
        elif kind == "history":
            row = _items(record.history.item)
            history[row.pop("_step")] = {k: v for k, v in row.items() if not k.startswith("_")}
        elif kind == "config":
            config.update(_items(record.config.update))
        elif kind == "summary":
            summary.update(_items(record.summary.update))
    return project, history, config, summary


# The sizes and chunk of the other tiny driver runs (conftest's tiny_run): their compiled
# programs serve through the persistent compilation cache.
DRIVER_TINY = [
    *("--env", "driver", "--seeds", "2", "--iterations", "4", "--num-envs", "2"),
    *("--rollout-length", "20", "--chunk-size", "2", "--quiet"),
]


def test_a_wandb_offline_run_holds_the_metrics_config_and_summary_of_a_run(tmp_path, monkeypatch):
    from emgail_jax import run

    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path))
    monkeypatch.setenv("WANDB_SILENT", "true")
    out = tmp_path / "run"
    assert run.main([*DRIVER_TINY, "--out", str(out), "--wandb", "emgail-test"]) == 0
    import wandb

    wandb.teardown()  # W&B's service writes the log after finish(); at the latest as it stops
    project, history, config, summary = _offline_run(tmp_path)
    assert project == "emgail-test"
    with open(out / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    expected = {}
    for row in rows:
        step, seed = int(row.pop("iteration")), int(row.pop("seed"))
        for name, cell in row.items():
            if cell:
                expected.setdefault(step, {})[f"seed_{seed}/{name}"] = float(cell)
    assert sorted(history) == [1, 2, 3, 4] == sorted(expected)
    for step, values in expected.items():
        assert sorted(history[step]) == sorted(values)  # the finite metrics, as TensorBoard
        for key, value in values.items():  # metrics.csv keeps 6 significant digits
            assert history[step][key] == pytest.approx(value, rel=1e-5, abs=1e-12), key
    stored = json.loads((out / "summary.json").read_text())
    assert config["env"] == "driver" and config["algo"] == "emgail"
    assert config["config"] == stored["config"]
    assert summary["status"] == "completed"
    assert summary["final/erd"] == pytest.approx(stored["final"]["erd"])
    assert summary["final/cluster_accuracy"] == pytest.approx(stored["final"]["cluster_accuracy"])


def test_wandb_missing_is_a_one_line_error_before_anything_is_written(
    tmp_path, monkeypatch, capsys
):
    import sys

    from emgail_jax import run

    monkeypatch.setitem(sys.modules, "wandb", None)  # import wandb raises ImportError
    out = tmp_path / "run"
    assert run.main([*DRIVER_TINY, "--out", str(out), "--wandb", "emgail-test"]) == 2
    err = capsys.readouterr().err.strip()
    assert err == "error: --wandb needs the wandb package: pip install 'emgail-jax[wandb]'"
    assert not out.exists()
