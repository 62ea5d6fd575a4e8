"""Plausible-but-wrong and corrupt data at the corpus boundary, the training loop's non-finite guard, atomic
output folders under signals, and workers that exit with their parent. Every bad input: the message is
asserted (file or clip named) and nothing is written."""
import json
import os
import pickle
import re
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.checks import load_npy, NonFiniteError
from dualtalker_lite.files import AtomicOutputDir, repo_root

ENV = {**os.environ, "PYTHONPATH": str(repo_root())}  # subprocesses import this checkout's package

V, T, SR = 20, 30, 16000


def _template():
    rng = np.random.default_rng(0)
    return (rng.uniform(-0.1, 0.1, size=(V, 3))).astype(np.float32)  # a 0.2 m "head"


def make_corpus(root, clips=("A_s01", "A_s02", "A_s03"), splits=None):
    """A tiny corpus in FaceFormer's layout: speaker A, 1 s clips, 20 vertices moving by a few mm."""
    (root / "wav").mkdir(parents=True)
    (root / "vertices_npy").mkdir()
    tpl = _template()
    for i, name in enumerate(clips):
        sf.write(root / "wav" / f"{name}.wav", 0.1 * np.sin(np.arange(SR) * 0.05 * (i + 1)), SR)
        motion = 0.003 * np.sin(np.linspace(0, 6, T))[:, None, None] * np.ones((T, V, 3))
        np.save(root / "vertices_npy" / f"{name}.npy", (tpl + motion).reshape(T, V * 3).astype(np.float32))
    np.savez(root / "templates.npz", A=tpl.reshape(-1))
    np.save(root / "faces.npy", np.array([[0, 1, 2], [2, 3, 4]], np.int64))
    (root / "regions.json").write_text(json.dumps({"lips": [0, 1, 2]}))
    splits = splits or {"train": list(clips[:2]), "test_a": list(clips[2:])}
    meta = {"format": "faceformer", "fps": 30, "sample_rate": SR, "n_vertices": V, "splits": splits,
            "clips": {c: {"subject": "A", "n_frames": T} for c in clips}}
    (root / "metadata.json").write_text(json.dumps(meta))
    return root


def _listing(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_valid_tiny_corpus_loads(tmp_path):
    c = Corpus(make_corpus(tmp_path / "c"))
    assert c.vertices("A_s01").shape == (T, V * 3) and c.train_speakers == ["A"]


@pytest.mark.parametrize("text, message", [
    ('{"format": "faceformer", "clips": {', "invalid JSON at line 1, column"),
    ('{"format": "faceformer", "splits": {}}', "has no 'clips' table"),
    ('[1, 2]', "expected a JSON object at the top level"),
    ('{"clips": {"x": {"text": "hi"}}}', "clip 'x' has no 'subject'"),
])
def test_broken_metadata(tmp_path, text, message):
    root = make_corpus(tmp_path / "c")
    (root / "metadata.json").write_text(text)
    before = _listing(root)
    with pytest.raises(ValueError, match="metadata.json") as e:
        Corpus(root)
    assert message in str(e.value) and "\n" not in str(e.value)
    assert _listing(root) == before


def test_clips_shared_between_train_and_test(tmp_path):
    root = make_corpus(tmp_path / "c", splits={"train": ["A_s01", "A_s02"], "test_a": ["A_s02", "A_s03"]})
    with pytest.raises(ValueError, match=r"1 clip\(s\) are in both 'train' and 'test_a' \(e.g. \['A_s02'\]\)"):
        Corpus(root)


def test_empty_split(tmp_path):
    root = make_corpus(tmp_path / "c", splits={"train": ["A_s01", "A_s02", "A_s03"], "val": []})
    with pytest.raises(ValueError, match="split 'val' is empty"):
        Corpus(root).split("val")


def test_random_bytes_npy(tmp_path):
    root = make_corpus(tmp_path / "c")
    (root / "vertices_npy" / "A_s01.npy").write_bytes(os.urandom(300))
    with pytest.raises(ValueError) as e:
        Corpus(root).vertices("A_s01")
    msg = str(e.value)
    assert "A_s01.npy: not a valid .npy file" in msg and "allow_pickle" not in msg


def test_pickled_npy_is_refused_not_loaded(tmp_path):
    root = make_corpus(tmp_path / "c")
    np.save(root / "vertices_npy" / "A_s01.npy", np.array([{"evil": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match="A_s01.npy: holds pickled Python objects.*refused"):
        Corpus(root).vertices("A_s01")


def test_nan_in_one_frame_names_clip_and_frame(tmp_path):
    root = make_corpus(tmp_path / "c")
    path = root / "vertices_npy" / "A_s02.npy"
    v = np.load(path)
    v[7, :30] = np.nan  # 30 NaN values in one frame
    np.save(path, v)
    with pytest.raises(ValueError, match=r"clip 'A_s02' .*30 NaN/infinite vertex value\(s\) in 1 frame\(s\), "
                                         r"first at frame 7"):
        Corpus(root).vertices("A_s02")


def test_millimetres_instead_of_metres(tmp_path):
    root = make_corpus(tmp_path / "c")
    path = root / "vertices_npy" / "A_s01.npy"
    np.save(path, np.load(path) * 1000)
    with pytest.raises(ValueError, match="clip 'A_s01'.*millimetres instead of metres"):
        Corpus(root).vertices("A_s01")


def test_transposed_layout(tmp_path):
    root = make_corpus(tmp_path / "c")
    path = root / "vertices_npy" / "A_s01.npy"
    v = np.load(path).reshape(T, V, 3)
    np.save(path, v.transpose(0, 2, 1))  # (T, 3, V)
    with pytest.raises(ValueError, match=r"A_s01.npy: shape \(30, 3, 20\) looks like a transposed \(T, 3, V\)"):
        Corpus(root).vertices("A_s01")
    np.save(path, np.ascontiguousarray(v.transpose(0, 2, 1)).reshape(T, V * 3))  # the same, saved flat
    with pytest.raises(ValueError, match="clip 'A_s01'.*from the template.*transposed"):
        Corpus(root).vertices("A_s01")


def test_nan_template_and_mm_template(tmp_path):
    root = make_corpus(tmp_path / "c")
    tpl = _template()
    tpl[3, 0] = np.nan
    np.savez(root / "templates.npz", A=tpl.reshape(-1))
    with pytest.raises(NonFiniteError, match="template of speaker 'A'.*1 NaN"):
        Corpus(root).template("A")
    np.savez(root / "templates.npz", A=_template().reshape(-1) * 1000)
    with pytest.raises(ValueError, match="template of speaker 'A'.*millimetres instead of metres"):
        Corpus(root).template("A")


def test_templates_pkl_only_points_to_the_converter(tmp_path):
    root = make_corpus(tmp_path / "c")
    (root / "templates.npz").unlink()
    with open(root / "templates.pkl", "wb") as f:
        pickle.dump({"A": _template()}, f)
    with pytest.raises(FileNotFoundError, match="templates.pkl .*convert-templates"):
        Corpus(root).template("A")


def test_faces_out_of_range(tmp_path):
    root = make_corpus(tmp_path / "c")
    np.save(root / "faces.npy", np.array([[0, 1, 20]], np.int64))
    with pytest.raises(ValueError, match=r"faces.npy: triangle indices span \[0, 20\], outside the 20 vertices"):
        Corpus(root).faces


def test_load_npy_never_unpickles(tmp_path):
    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    np.save(tmp_path / "evil.npy", np.array([Evil()], dtype=object), allow_pickle=True)
    with pytest.raises(ValueError, match="evil.npy: holds pickled Python objects"):
        load_npy(tmp_path / "evil.npy")
    assert not marker.exists()


# ------------------------------------------------------------------------------------------ training
def test_training_stops_on_non_finite_loss_naming_the_clips(tmp_path):
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.dataset import TalkingFaceDataset, collate
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
    from dualtalker_lite.checkpoints import save_checkpoint
    from dualtalker_lite.train import TrainConfig, train

    corpus = Corpus(sample_path())
    ds = TalkingFaceDataset(corpus, "train")
    good = collate([ds[0], ds[1]])
    bad = collate([ds[2], ds[3]])
    bad["vertices"][1, 5, :30] = float("nan")  # 30 NaN values in one frame of one clip
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160, n_speakers=8)
    model = DualTalker(cfg)
    expected = "non-finite vertices or template in clip\\(s\\) " + re.escape(str(bad["name"]))
    with pytest.raises(NonFiniteError, match=expected):
        train(model, [good, bad], TrainConfig.tiny(epochs=1, progress=False, max_frames=None))  # mean-motion pass
    with pytest.raises(NonFiniteError) as e:
        train(model, [good, bad], TrainConfig.tiny(epochs=1, progress=False, validate_every=0, max_frames=None,
                                                   mean_init=False))
    msg = str(e.value)
    assert "non-finite loss" in msg and "epoch 1, step 2" in msg and str(bad["name"]) in msg
    for p in model.parameters():  # the NaN never reached the weights
        assert torch.isfinite(p).all()
    save_checkpoint(tmp_path / "ok.pt", model, cfg)  # the last good weights can still be saved
    assert (tmp_path / "ok.pt").is_file()


# ------------------------------------------------------------------------------ atomic outputs, signals
def test_atomic_output_dir_cleans_up_on_exception(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with AtomicOutputDir(out) as tmp:
            (tmp / "vertices.npy").write_bytes(b"half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_atomic_output_dir_cleans_up_on_signal(tmp_path, sig):
    code = textwrap.dedent(f"""
        import sys, time
        from dualtalker_lite.files import AtomicOutputDir
        with AtomicOutputDir({str(tmp_path / "out")!r}) as tmp:
            (tmp / "part.npy").write_bytes(b"x")
            print("ready", flush=True)
            time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=ENV)
    assert proc.stdout.readline().strip() == b"ready"
    assert sorted(p.name.split(".")[1] + "." + p.name.rsplit(".", 1)[1] for p in tmp_path.iterdir()) == \
        ["out.lock", "out.tmp"]  # the hidden temporary folder and the claim's lock file
    proc.send_signal(sig)
    proc.wait(timeout=30)
    assert proc.returncode != 0
    assert list(tmp_path.iterdir()) == []


def _alive(pid):
    try:
        with open(f"/proc/{pid}/status") as f:
            return "zombie" not in f.read()
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_worker_exits_when_its_parent_is_killed(tmp_path):
    pidfile = tmp_path / "worker.pid"
    worker = (f"import os, time; from dualtalker_lite.processes import watch_parent; watch_parent(0.2); "
              f"open({str(pidfile)!r}, 'w').write(str(os.getpid())); time.sleep(120)")
    parent = (f"import subprocess, sys, time; subprocess.Popen([sys.executable, '-c', {worker!r}]); "
              f"time.sleep(120)")
    proc = subprocess.Popen([sys.executable, "-c", parent], env=ENV)
    for _ in range(300):
        if pidfile.exists() and pidfile.read_text():
            break
        time.sleep(0.1)
    pid = int(pidfile.read_text())
    assert _alive(pid)
    proc.kill()  # SIGKILL: the parent gets no chance to clean up
    proc.wait()
    for _ in range(100):
        if not _alive(pid):
            break
        time.sleep(0.1)
    assert not _alive(pid), "the orphaned worker is still running"


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_interrupted_checkpoint_save_leaves_no_tmp_file(tmp_path, sig):
    code = textwrap.dedent(f"""
        import time, torch
        from dualtalker_lite.files import atomic_torch_save
        real_save = torch.save
        def slow_save(obj, f):  # the file is half-way: written but not yet renamed
            real_save(obj, f)
            print("ready", flush=True)
            time.sleep(60)
        torch.save = slow_save
        atomic_torch_save({{"w": torch.zeros(10)}}, {str(tmp_path / "model.pt")!r})
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            env=ENV)
    assert proc.stdout.readline().strip() == b"ready"
    assert [p.suffix for p in tmp_path.iterdir()] == [".tmp"]
    proc.send_signal(sig)
    proc.wait(timeout=30)
    assert proc.returncode != 0 and list(tmp_path.iterdir()) == []


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_runner_pool_workers_exit_when_the_runner_is_killed(tmp_path):
    """The experiment runner's real pool set-up (spawn + _worker_init), its parent killed with SIGKILL."""
    code = textwrap.dedent("""
        import os, time
        from concurrent.futures import ProcessPoolExecutor
        from multiprocessing import get_context
        from dualtalker_lite.experiments.runner import _worker_init
        if __name__ == "__main__":
            pool = ProcessPoolExecutor(2, mp_context=get_context("spawn"), initializer=_worker_init,
                                       initargs=(os.getpid(),))
            futures = [pool.submit(time.sleep, 120) for _ in range(2)]
            time.sleep(0.5)
            while len(pool._processes) < 2:
                time.sleep(0.1)
            print(" ".join(str(p) for p in pool._processes), flush=True)
            time.sleep(120)
    """)
    (tmp_path / "runner.py").write_text(code)
    proc = subprocess.Popen([sys.executable, str(tmp_path / "runner.py")], stdout=subprocess.PIPE, env=ENV)
    workers = [int(p) for p in proc.stdout.readline().split()]
    assert len(workers) == 2 and all(_alive(w) for w in workers)
    proc.kill()  # possibly while the workers are still importing: they must notice once started
    proc.wait()
    for _ in range(600):
        if not any(_alive(w) for w in workers):
            break
        time.sleep(0.1)
    assert not any(_alive(w) for w in workers), "pool workers outlived the killed runner"
