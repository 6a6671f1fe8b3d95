"""Packed tables (``triplesumo pack``): a finished output folder's large ``*.csv`` gzipped in place
(``NAME.csv.gz``), for keeping it beside a docs page. A packed folder reads, plots and resumes as the
plain one did; packing is deterministic; small tables stay plain; a table in both forms is refused with
both names. (Training's resume from a packed run: tests/test_train.py; a packed reproduction:
tests/test_reproduce.py.)"""

from __future__ import annotations

import gzip
import shutil
import zlib
from pathlib import Path

import numpy as np
import pytest

from conftest import tiny
from triplesumo.cli import main
from triplesumo.evaluation.evaluate import EvaluateConfig, evaluate
from triplesumo.evaluation.metrics_csv import (
    open_table,
    pack_tables,
    read_table_bytes,
    repair_metrics_csv,
    stored,
    table_exists,
    unpack_table,
)
from triplesumo.evaluation.plots import read_metrics_csv
from triplesumo.train.loop import train
from triplesumo.train.run_folder import plot_metrics


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished tiny training run (4 epochs), plain."""
    return train(tiny(tmp_path_factory.mktemp("runs"))).run_dir


@pytest.mark.slow  # 14 s alone on the shared 2-core box
def test_a_packed_run_reads_and_plots_as_the_plain_one(run: Path, tmp_path: Path) -> None:
    packed = tmp_path / "packed"
    shutil.copytree(run, packed)
    plain_bytes = {p.relative_to(run): p.read_bytes() for p in run.rglob("*.csv")}
    done = pack_tables(packed, min_bytes=0)
    assert {p.relative_to(packed) for p in done} == {Path(f"{r}.gz") for r in plain_bytes}
    assert not list(packed.rglob("*.csv"))
    from triplesumo.evaluation.metrics_csv import tables_in

    names = sorted(p.name for p in run.glob("*.csv"))  # each table by its plain name, plain or packed
    assert tables_in(packed) == [packed / n for n in names] and tables_in(run) == [run / n for n in names]
    assert len(names) >= 2
    for rel, data in plain_bytes.items():
        assert gzip.decompress((packed / f"{rel}.gz").read_bytes()) == data  # a standard gzip file
        assert read_table_bytes(packed / rel) == data and table_exists(packed / rel)
        assert stored(packed / rel) == packed / f"{rel}.gz"
        with open_table(packed / rel) as fh:
            assert fh.read() == data.decode()
    ours, theirs = read_metrics_csv(run / "metrics.csv"), read_metrics_csv(packed / "metrics.csv")
    assert ours.keys() == theirs.keys() and all(np.array_equal(ours[k], theirs[k]) for k in ours)
    for png in (packed / "plots").glob("*.png"):
        png.unlink()
    assert sorted(p.name for p in plot_metrics(packed, 2)) == sorted(p.name for p in (run / "plots").glob("*.png"))
    # with pandas, as any user would read it
    pd = pytest.importorskip("pandas")
    assert pd.read_csv(packed / "metrics.csv.gz").equals(pd.read_csv(run / "metrics.csv"))


def test_packing_is_deterministic_and_leaves_small_tables_plain(run: Path, tmp_path: Path) -> None:
    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(run, a)
    shutil.copytree(run, b)
    size = (run / "metrics.csv").stat().st_size
    assert [p.name for p in pack_tables(a, min_bytes=size)] == ["metrics.csv.gz"]  # learning.csv is smaller
    assert (a / "learning.csv").is_file() and not (a / "metrics.csv").exists()
    (b / "metrics.csv").chmod(0o644)
    mtime = (b / "metrics.csv").stat().st_mtime
    pack_tables(b, min_bytes=size)
    assert (a / "metrics.csv.gz").read_bytes() == (b / "metrics.csv.gz").read_bytes()
    assert (b / "metrics.csv.gz").stat().st_mode & 0o777 == 0o644 and (b / "metrics.csv.gz").stat().st_mtime == mtime
    assert pack_tables(a, min_bytes=size) == []  # packed already: nothing to do


def test_a_table_in_both_forms_is_refused_naming_both(run: Path, tmp_path: Path) -> None:
    folder = tmp_path / "both"
    shutil.copytree(run, folder)
    (folder / "metrics.csv.gz").write_bytes(gzip.compress((folder / "metrics.csv").read_bytes()))
    for call in (lambda: stored(folder / "metrics.csv"), lambda: read_metrics_csv(folder / "metrics.csv"),
                 lambda: pack_tables(folder, min_bytes=0)):
        with pytest.raises(ValueError, match=r"metrics\.csv and .*metrics\.csv\.gz are both there"):
            call()
    assert (folder / "metrics.csv").is_file() and (folder / "metrics.csv.gz").is_file()  # nothing lost


def test_a_damaged_packed_table_names_its_file(tmp_path: Path) -> None:
    (tmp_path / "metrics.csv.gz").write_bytes(b"not gzip at all")
    with pytest.raises(ValueError, match=r"metrics\.csv\.gz: not a gzipped table"):
        read_table_bytes(tmp_path / "metrics.csv")
    with pytest.raises(FileNotFoundError, match=r"other\.csv not found \(nor other\.csv\.gz\)"):
        read_table_bytes(tmp_path / "other.csv")
    assert (tmp_path / "metrics.csv.gz").read_bytes() == b"not gzip at all"


def zlib_error(data: bytes) -> bool:
    """Whether gunzipping ``data`` fails inside its deflate stream (``zlib.error``, not a CRC or length check)."""
    try:
        gzip.decompress(data)
    except zlib.error:
        return True
    except (OSError, EOFError):
        return False
    return False


def test_a_packed_table_damaged_mid_stream_is_named_by_plot_and_both_resumes(
        run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    folder, evaluation = tmp_path / "run", tmp_path / "evaluation"
    shutil.copytree(run, folder)
    evaluate_argv = ["evaluate", "--policy", str(run / "policy"), "--baselines", "--epochs", "2",
                     "--steps-per-epoch", "20", "--n-envs", "2", "--no-progress", "--out", str(evaluation),
                     "--policies", "spider=random", "ant=zero"]
    assert main(evaluate_argv) == 0
    damaged = []
    for table in (folder / "metrics.csv", evaluation / "trained" / "metrics.csv"):
        pack_tables(table.parent, min_bytes=0)
        packed = stored(table).read_bytes()  # type: ignore[union-attr]
        flipped = (packed[:k] + bytes(b ^ 0xFF for b in packed[k:k + 8]) + packed[k + 8:]  # bytes flipped mid-stream
                   for k in range(10, len(packed) - 16))  # (after the 10-byte header, before the CRC)
        bad = next(b for b in flipped if zlib_error(b))  # what readers met until now: zlib.error, naming no file
        stored(table).write_bytes(bad)  # type: ignore[union-attr]
        damaged.append(stored(table))
    before = {p: p.read_bytes() for f in (folder, evaluation) for p in f.rglob("*") if p.is_file()}
    capsys.readouterr()
    for argv, table in ((["plot", str(folder)], damaged[0]),
                        (["train", "--resume", str(folder), "--epochs", "6"], damaged[0]),
                        ([*evaluate_argv, "--resume"], damaged[1])):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err
        assert f"{table}: not a gzipped table, or a damaged one" in err, (argv, err)
    assert {p: p.read_bytes() for f in (folder, evaluation) for p in f.rglob("*") if p.is_file()} == before


def test_a_torn_packed_table_is_unpacked_then_cut_back(run: Path, tmp_path: Path) -> None:
    lines = (run / "metrics.csv").read_text().splitlines(keepends=True)
    torn = "".join(lines[:3]) + lines[3][:10]  # two finished rows and a torn third
    (tmp_path / "metrics.csv.gz").write_bytes(gzip.compress(torn.encode()))
    assert repair_metrics_csv(tmp_path / "metrics.csv") == 2
    assert (tmp_path / "metrics.csv").read_text() == "".join(lines[:3])
    assert not (tmp_path / "metrics.csv.gz").exists()
    assert unpack_table(tmp_path / "metrics.csv") is False  # plain already


@pytest.mark.slow  # 9 s alone on the shared 2-core box
def test_a_packed_evaluation_resumes_to_the_rows_of_an_uninterrupted_one(run: Path, tmp_path: Path) -> None:
    def cfg(out: Path, epochs: int, resume: bool = False) -> EvaluateConfig:
        return EvaluateConfig(learner="bug", policy=(str(run / "policy"),), baselines=(), epochs=epochs,
                              steps_per_epoch=20, n_envs=2, progress=False, out=str(out), resume=resume,
                              policies=("spider=random", "ant=zero"))

    evaluate(cfg(tmp_path / "whole", 4))
    evaluate(cfg(tmp_path / "part", 2))
    packed = pack_tables(tmp_path / "part", min_bytes=0)
    assert any(p.name == "metrics.csv.gz" for p in packed)
    summary = evaluate(cfg(tmp_path / "part", 4, resume=True))
    assert summary["candidates"]["trained"]["n"] == 4
    whole = (tmp_path / "whole" / "trained" / "metrics.csv").read_text()
    assert (tmp_path / "part" / "trained" / "metrics.csv").read_text() == whole
    # a packed evaluation is still refused as a folder that holds one (no --resume): nothing overwritten
    pack_tables(tmp_path / "whole", min_bytes=0)
    with pytest.raises(FileExistsError, match="already holds an evaluation"):
        evaluate(cfg(tmp_path / "whole", 4))


def test_the_pack_command_packs_and_says_what_it_saved(run: Path, tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    folder = tmp_path / "cli"
    shutil.copytree(run, folder)
    assert main(["pack", str(folder), "--min-kb", "0"]) == 0
    out = capsys.readouterr().out
    assert f"{folder}: packed 2 table(s)" in out and "read as before" in out
    assert not list(folder.rglob("*.csv")) and table_exists(folder / "metrics.csv")
    assert main(["pack", str(tmp_path / "missing")]) == 2
    assert "missing: not a folder" in capsys.readouterr().err


def test_a_table_written_whole_replaces_its_packed_copy(tmp_path: Path) -> None:
    from triplesumo.evaluation.metrics_csv import write_table

    (tmp_path / "summary.csv.gz").write_bytes(gzip.compress(b"a,b\n1,2\n"))
    write_table(tmp_path / "summary.csv", b"a,b\n3,4\n")
    assert read_table_bytes(tmp_path / "summary.csv") == b"a,b\n3,4\n"
    assert not (tmp_path / "summary.csv.gz").exists()


def test_a_table_still_being_written_is_left_plain(run: Path, tmp_path: Path,
                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    """A run appending a row while its folder is packed: the table stays plain, with every row, and the error
    says why."""
    import triplesumo.evaluation.metrics_csv as tables

    folder = tmp_path / "live"
    shutil.copytree(run, folder)
    compress = gzip.compress

    def while_a_row_is_appended(data: bytes, *args: object, **kw: object) -> bytes:
        with (folder / "metrics.csv").open("a") as fh:
            fh.write("a row written meanwhile\n")
        return compress(data, *args, **kw)  # type: ignore[arg-type]

    monkeypatch.setattr(tables.gzip, "compress", while_a_row_is_appended)
    with pytest.raises(ValueError, match=r"metrics\.csv changed while it was being packed .* left plain"):
        pack_tables(folder, min_bytes=(run / "metrics.csv").stat().st_size)
    assert not (folder / "metrics.csv.gz").exists()
    assert (folder / "metrics.csv").read_text().endswith("a row written meanwhile\n")
