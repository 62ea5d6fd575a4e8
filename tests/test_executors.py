"""The experiment runner's executors (issue 45 item 2): ``--executor dask`` (a 2-worker LocalCluster) gives the
``--executor local`` table bit for bit; a worker that dies fails its run alone; failed runs leave the finished ones
in a file that ``--reuse`` takes; each results file records its executor; a bad ``--executor`` is one line."""
import json
import textwrap

import pytest

from dualtalker_lite import experiments as ex
from dualtalker_lite.experiments import command, runner
from dualtalker_lite.experiments.specs import RunSpec

pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py

pytest.importorskip("distributed", reason="the [cluster] extra (dask.distributed) is not installed")


@pytest.fixture(scope="module")
def local_main(tmp_path_factory):
    """The main table in --quick mode with the default executor (this process)."""
    out = tmp_path_factory.mktemp("local")
    ex.main(["--table", "main", "--quick", "--out", str(out), "--no-progress"])
    return json.loads((out / "main.json").read_text())


def test_dask_local_cluster_reproduces_the_local_table_bit_for_bit(local_main, tmp_path):
    ex.main(["--table", "main", "--quick", "--executor", "dask", "--processes", "2", "--out", str(tmp_path),
             "--no-progress"])
    dask = json.loads((tmp_path / "main.json").read_text())
    assert local_main["executor"] == "local (1 process)"
    assert dask["executor"] == "dask LocalCluster (2 worker processes)" and "--executor dask" in dask["command"]
    assert [r["row"] for r in dask["runs"]] == [r["row"] for r in local_main["runs"]]
    for a, b in zip(local_main["runs"], dask["runs"]):
        assert a["metrics"] == b["metrics"], a["row"]            # every float equal, not close
        assert a["loss_history"] == b["loss_history"], a["row"]
    trained = [r for r in dask["runs"] if r["row"] != "Static template"]
    assert len({r["pid"] for r in trained}) >= 1 and all(r["pid"] != local_main["runs"][0]["pid"] for r in trained)


def test_reuse_works_across_executors(local_main, tmp_path, monkeypatch, capsys):
    """A table computed locally is taken over by a dask invocation: nothing is computed (no cluster starts)."""
    (tmp_path / "local.json").write_text(json.dumps(local_main))

    def no_runs(jobs, *a, **k):
        assert jobs == [], "a reused run was recomputed"
        return []

    monkeypatch.setattr(command, "run_specs", no_runs)
    ex.main(["--table", "main", "--quick", "--executor", "dask", "--out", str(tmp_path / "out"), "--no-progress",
             "--reuse", str(tmp_path / "local.json")])
    assert f"0 distinct runs to compute, {len(local_main['runs'])} reused" in capsys.readouterr().out
    again = json.loads((tmp_path / "out" / "main.json").read_text())
    assert [r["metrics"] for r in again["runs"]] == [r["metrics"] for r in local_main["runs"]]


def test_a_worker_that_dies_fails_its_run_alone(tmp_path, monkeypatch):
    """A plugin model whose construction kills its worker process (os._exit): that run fails with one line naming
    the row, the seed and the cause; the other run finishes on the cluster and is returned."""
    (tmp_path / "dies_plugin.py").write_text(textwrap.dedent("""
        import os
        from dualtalker_lite.models import registry
        from dualtalker_lite.models.baselines import VocaConfig, VocaStyle

        class Dies(VocaStyle):  # a class of its own: the registry keeps one entry per class name
            pass

        def build(*args, **kwargs):
            os._exit(3)  # the worker process dies mid-run

        registry.register(registry.ModelEntry("dies", Dies, VocaConfig, build))
    """))
    monkeypatch.setenv("PYTHONPATH", str(tmp_path))  # the workers start after this: they import the plugin
    monkeypatch.setenv("DUALTALKER_PLUGINS", "dies_plugin")
    monkeypatch.syspath_prepend(str(tmp_path))
    failures = []
    jobs = [(RunSpec(row="dies", model="dies", features="logmel"), 0),
            (RunSpec(row="VOCA-style", model="voca", features="logmel"), 0)]
    results = runner.run_specs(jobs, 1, processes=2, quick=True, progress=False, executor="dask", failures=failures)
    assert results[1] is not None, failures
    assert results[0] is None and results[1]["row"] == "VOCA-style" and results[1]["epochs"] == 1
    assert failures == ["run 'dies' seed 0 failed: its worker died (KilledWorker)"]


def test_failed_runs_keep_the_finished_ones_for_reuse(local_main, tmp_path, monkeypatch, capsys):
    """Exit 1, one ``error:`` line per failed run and one saying where the finished runs are; no table is written;
    ``--reuse`` of that file then computes only the failed run."""
    real = command.run_specs

    def first_fails(jobs, *a, failures, **k):
        results = real(jobs, *a, failures=failures, **k)
        failures.append(f"run {jobs[0][0].row!r} seed 0 failed: its worker died (KilledWorker)")
        return [None, *results[1:]]

    monkeypatch.setattr(command, "run_specs", first_fails)
    out = tmp_path / "out"
    with pytest.raises(SystemExit) as e:
        ex.main(["--table", "main", "--quick", "--out", str(out), "--no-progress"])
    assert e.value.code == 1
    n = len(local_main["runs"])
    partial = out / "partial_runs.json"
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2 and err[0].startswith("error: run ") and err[0].endswith("failed: its worker died "
                                                                                  "(KilledWorker)")
    assert err[1] == (f"error: 1 of {n} runs failed; the {n - 1} that finished are kept in {partial}: run the same "
                      f"command with --reuse {partial} to compute only the failed ones")
    assert sorted(p.name for p in out.iterdir()) == ["partial_runs.json"]  # no table from an incomplete set
    kept = json.loads(partial.read_text())
    assert len(kept["runs"]) == n - 1 and kept["executor"] == "local (1 process)" and len(kept["failed"]) == 1
    monkeypatch.setattr(command, "run_specs", real)
    ex.main(["--table", "main", "--quick", "--out", str(out), "--no-progress", "--reuse", str(partial)])
    assert f"1 distinct runs to compute, {n - 1} reused" in capsys.readouterr().out
    final = json.loads((out / "main.json").read_text())
    assert [r["metrics"] for r in final["runs"]] == [r["metrics"] for r in local_main["runs"]]


@pytest.mark.parametrize("value", ["ray", "dask://", "dask://host", "dask://host:port", "tcp:/host:1"])
def test_a_bad_executor_is_one_line(value, capsys):
    with pytest.raises(SystemExit) as e:
        command.parse_args(["--executor", value])
    assert e.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].endswith(
        f"--executor {value!r}: expected local, dask or dask://HOST:PORT (a running dask scheduler)")


def test_executor_addresses():
    assert runner.executor_kind("local") == "local" and runner.executor_kind("dask") == "dask"
    assert runner.executor_kind("dask://10.0.0.5:8786") == "tcp://10.0.0.5:8786"
    assert runner.executor_kind("tcp://node1:8786") == "tcp://node1:8786"
