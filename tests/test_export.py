"""glTF morph-target export and the self-contained HTML viewer (issue 22), checked by the reference tools.

- the streaming PCA meets its tolerance at every vertex of every frame (randomized sketch included);
- the Khronos glTF validator (npm ``gltf-validator``, run with node) reports 0 errors and 0 warnings;
- the .html plays in a real browser (Debian's chromium driven by Playwright, which downloads no browser):
  play moves the mesh and advances the audio clock, the scrub bar seeks both, no network request is made, and a
  screenshot is left in ``runs/screenshots/`` for a human to look at.

The validator and three.js come from ``npm ci --prefix tools/node`` and chromium from ``apt-get install chromium``
(both done by ``make test-tools``, which ``make test`` runs first); the tests that need them are skipped, saying
what to install, where they are absent.
"""
import base64
import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.export.gltf import morph_basis, read_gltf_animation, split_signed, write_gltf
from dualtalker_lite.export.html import SCENE_MODULE, iframe_html, page_dir, vendor_dir, viewer_html, write_html

ROOT = Path(__file__).resolve().parents[1]
NODE_MODULES = ROOT / "tools" / "node" / "node_modules"
VALIDATE_JS = """
const fs = require('fs'), path = require('path');
const validator = require(process.argv[2]);
const file = process.argv[3];
const external = (uri) => new Promise((ok, no) => {
  try { ok(new Uint8Array(fs.readFileSync(path.join(path.dirname(file), decodeURIComponent(uri))))); }
  catch (e) { no(String(e)); } });
validator.validateBytes(new Uint8Array(fs.readFileSync(file)), {maxIssues: 50, externalResourceFunction: external})
  .then((report) => console.log(JSON.stringify(report.issues)))
  .catch((e) => { console.error(String(e)); process.exit(1); });
"""


@pytest.fixture(scope="module")
def corpus():
    return Corpus(sample_path())


@pytest.fixture(scope="module")
def clip(corpus):
    """The rig's ground truth of a 10.7 s multi-sentence clip: (T, V*3) metres, its template, faces and speech."""
    name = "SPK01_long01"
    return corpus.vertices(name), corpus.template("SPK01"), corpus.faces, corpus.wave(name)


def _vertex_error(a, b):
    return np.linalg.norm((np.asarray(a, np.float64) - b).reshape(len(a), -1, 3), axis=2)


def test_randomized_streaming_pca_meets_the_tolerance_at_every_vertex(clip, tmp_path):
    """A tiny first sketch (l = 4) with small blocks: l doubles until K components reach 0.1 mm everywhere, the
    file of the clip read as a memory map reproduces every frame within the tolerance."""
    verts, template, _, _ = clip
    np.save(tmp_path / "v.npy", verts)
    mm = np.load(tmp_path / "v.npy", mmap_mode="r")
    basis = morph_basis(mm, template, tol=1e-4, block=97, sketch=4)
    assert not basis.exact and basis.sketch_size >= basis.components.shape[0] > 4
    rec = template + basis.coeffs @ basis.components
    assert _vertex_error(rec, verts).max() < 1e-4
    np.testing.assert_allclose(basis.components @ basis.components.T, np.eye(len(basis.components)), atol=1e-4)
    exact = morph_basis(verts[:40], template, tol=1e-4)  # T <= l: the frames' own row space
    assert exact.exact and _vertex_error(template + exact.coeffs @ exact.components, verts[:40]).max() < 1e-4
    targets, weights, names = split_signed(basis.components, basis.coeffs)
    assert weights.min() >= 0 and weights.max() <= 1 and len(names) == len(targets) <= 2 * len(basis.components)
    np.testing.assert_allclose(weights @ targets, basis.coeffs @ basis.components, atol=1e-7)


def test_gltf_file_holds_template_targets_weights_and_names_its_audio(clip, tmp_path):
    verts, template, faces, wave = clip
    report = write_gltf(tmp_path / "animation.glb", verts, faces, template, wave=wave)
    assert report.max_error < 1e-4 and report.audio == tmp_path / "animation.wav"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["animation.glb", "animation.wav"]  # no .partial left
    assert "max vertex error" in report.line() and "mm" in report.line()
    got = read_gltf_animation(tmp_path / "animation.glb")
    np.testing.assert_array_equal(got["base"].reshape(-1), template)
    np.testing.assert_array_equal(got["faces"], faces)
    np.testing.assert_allclose(got["times"], np.arange(len(verts)) / 30, atol=1e-4)
    rec = got["base"].reshape(-1) + got["weights"] @ got["targets"].reshape(len(got["targets"]), -1)
    err = _vertex_error(rec, verts)
    assert err.max() < 1e-4 and abs(err.max() - report.max_error) < 1e-6
    assert got["weights"].min() >= 0 and got["weights"].max() <= 1
    audio = got["extras"]["audio"]
    assert audio["uri"] == "animation.wav" and audio["sampleRate"] == 16000 and audio["startTime"] == 0
    back, sr = sf.read(tmp_path / "animation.wav")
    assert sr == 16000 and len(back) == len(wave) and np.abs(back - wave).max() < 1e-4
    # the size target: < 5 MB per minute at < 0.1 mm (here 10.7 s)
    assert report.bytes / (len(verts) / 30 / 60) < 5e6


def test_glb_is_written_piece_by_piece_as_pygltflib_writes_it(clip, tmp_path):
    """write_gltf streams the GLB (header, JSON chunk, BIN chunk) without joining the buffer in memory; pygltflib,
    the reference, loads it and saves it again to the very same bytes."""
    import pygltflib

    verts, template, faces, wave = clip
    write_gltf(tmp_path / "a.glb", verts[:100], faces, template, wave=wave[:len(wave) * 100 // len(verts)])
    data = (tmp_path / "a.glb").read_bytes()
    assert data[:4] == b"glTF" and int.from_bytes(data[8:12], "little") == len(data)
    n_json = int.from_bytes(data[12:16], "little")
    assert data[16:20] == b"JSON" and (20 + n_json) % 4 == 0 and data[24 + n_json:28 + n_json] == b"BIN\0"
    pygltflib.GLTF2.load_binary(str(tmp_path / "a.glb")).save_binary(str(tmp_path / "b.glb"))
    assert (tmp_path / "b.glb").read_bytes() == data


def test_split_signed_by_hand():
    """Two components: c_0 in [-1, 2] gives a '+' target 2 B_0 and a '-' target -1 B_0; c_1 >= 0 only '+'."""
    components = np.array([[1.0, 0.0], [0.0, 1.0]], np.float32)
    coeffs = np.array([[2.0, 0.5], [-1.0, 0.0], [1.0, 0.25]], np.float32)  # (T, K)
    targets, weights, names = split_signed(components, coeffs)
    assert names == ["pc00+", "pc00-", "pc01+"] and weights.dtype == np.float32
    np.testing.assert_array_equal(targets, [[2, 0], [-1, 0], [0, 0.5]])
    np.testing.assert_array_equal(weights, [[1, 0, 1], [0, 1, 0], [0.5, 0, 0.5]])
    np.testing.assert_allclose(weights @ targets, coeffs @ components)


def test_bad_input_is_one_clear_error_and_leaves_no_file(clip, tmp_path):
    verts, template, faces, _ = clip
    bad = np.array(verts[:30])
    bad[12, 5] = np.nan
    with pytest.raises(ValueError, match="non-finite vertices at frame 12"):
        write_gltf(tmp_path / "a.glb", bad, faces, template)
    with pytest.raises(ValueError, match="faces index vertices outside"):
        write_gltf(tmp_path / "a.glb", verts[:30], faces + len(template), template)
    with pytest.raises(ValueError, match="template has"):
        write_gltf(tmp_path / "a.glb", verts[:30], faces, template[:-3])
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(ValueError, match="not a binary glTF"):
        viewer_html(b"<html>")


def test_motionless_and_single_frame_clips_still_export(clip, tmp_path):
    _, template, faces, _ = clip
    still = np.tile(template, (5, 1))
    report = write_gltf(tmp_path / "still.glb", still, faces, template)
    assert report.max_error == 0 and report.targets == 1
    one = write_gltf(tmp_path / "one.glb", still[:1] + 1e-3, faces, template)
    assert one.frames == 1 and one.max_error < 1e-4


def test_write_glb_is_a_deprecated_door_to_write_gltf(clip, tmp_path):
    """The old ``inference.write_glb`` still writes, for one release, the very bytes of ``write_gltf``, and warns
    naming it (CHANGELOG.md, Deprecated)."""
    from dualtalker_lite.inference import write_glb

    verts, template, faces, _ = clip
    write_gltf(tmp_path / "new.glb", verts[:40], faces, template, fps=30)  # write_glb's fps is inference.FPS, 30
    with pytest.warns(DeprecationWarning, match=r"export\.gltf\.write_gltf"):
        write_glb(tmp_path / "old.glb", verts[:40], faces, template=template)
    assert (tmp_path / "old.glb").read_bytes() == (tmp_path / "new.glb").read_bytes()


# ------------------------------------------------------------------------------------------ Khronos validator
def _absent(message: str):
    """Skip with ``message``, or fail where CI installed the tools (tools/test_tools.sh sets DUALTALKER_REQUIRE_EXPORT_TOOLS)."""
    if os.environ.get("DUALTALKER_REQUIRE_EXPORT_TOOLS"):
        pytest.fail("DUALTALKER_REQUIRE_EXPORT_TOOLS is set but " + message)
    pytest.skip(message)


def _validator():
    node = shutil.which("node")
    module = NODE_MODULES / "gltf-validator"
    if node is None or not module.is_dir():
        _absent("the Khronos glTF validator is not installed: `npm ci --prefix tools/node` (node >= 18; "
                    "make test-tools does it)")
    return node, module


@pytest.mark.tools
def test_khronos_gltf_validator_reports_no_error(clip, tmp_path):
    node, module = _validator()
    verts, template, faces, wave = clip
    write_gltf(tmp_path / "animation.glb", verts, faces, template, wave=wave)
    (tmp_path / "validate.js").write_text(VALIDATE_JS)
    out = subprocess.run([node, str(tmp_path / "validate.js"), str(module), str(tmp_path / "animation.glb")],
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    issues = json.loads(out.stdout)
    assert issues["numErrors"] == 0 and issues["numWarnings"] == 0, issues["messages"]


@pytest.mark.tools
def test_vendored_three_js_is_npm_three_0_170_0():
    """The committed files are byte-identical to npm's three@0.170.0 (tools/node/package-lock.json pins it)."""
    npm = NODE_MODULES / "three"
    if not npm.is_dir():
        _absent("npm three is not installed: `npm ci --prefix tools/node` (make test-tools does it)")
    assert json.loads((npm / "package.json").read_text())["version"] == "0.170.0"
    sources = {"three.module.min.js": "build", "GLTFLoader.js": "examples/jsm/loaders",
               "OrbitControls.js": "examples/jsm/controls", "BufferGeometryUtils.js": "examples/jsm/utils",
               "LICENSE": "."}
    for name, folder in sources.items():
        assert (vendor_dir() / name).read_bytes() == (npm / folder / name).read_bytes(), name


def test_html_page_inlines_everything(clip, tmp_path):
    verts, template, faces, wave = clip
    write_gltf(tmp_path / "a.glb", verts[:60], faces, template)
    page = write_html(tmp_path / "a.html", tmp_path / "a.glb", wave[:32000]).read_text()
    assert page.count("<script") == 2 and "<script src" not in page and "<link" not in page
    assert 'src="data:audio/wav;base64,' in page and '"three": "data:text/javascript;base64,' in page
    assert "../utils/BufferGeometryUtils.js" not in page  # the one relative import is renamed to the map's name
    frame = iframe_html(page)
    assert frame.startswith("<iframe srcdoc=") and "<script" not in frame  # escaped into the attribute
    assert f'"{SCENE_MODULE}": "data:text/javascript;base64,' in page  # the shared stage, inlined too


def test_one_stage_for_the_exported_and_the_live_page():
    """The three.js stage (renderer, lights, camera, orbit controls, framing) is written once, in
    export/page/scene.js: the exported viewer inlines it, the live page's import map serves it, and neither page
    builds a renderer or a light of its own."""
    from dualtalker_lite.export import html
    from dualtalker_lite.live.server import PAGE_DIR

    live_page = (PAGE_DIR / "index.html").read_text()
    assert f'"{SCENE_MODULE}": "/page/scene.js"' in live_page
    pages = {"export/html.py": html._PAGE, **{name: (PAGE_DIR / name).read_text() for name in ("live.js", "avatar.js")}}
    for name, source in pages.items():
        assert f"from '{SCENE_MODULE}'" in source, name
        for own in ("WebGLRenderer", "HemisphereLight", "DirectionalLight", "OrbitControls"):
            assert own not in source, (name, own)
    stage = (page_dir() / "scene.js").read_text()
    assert all(own in stage for own in ("WebGLRenderer", "HemisphereLight", "DirectionalLight", "OrbitControls"))


# ------------------------------------------------------------------------------------------ a real browser
def _chromium():
    exe = os.environ.get("DTL_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        _absent("no chromium: `apt-get install chromium` (Debian; make test-tools does it as root) or set DTL_CHROMIUM")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        _absent("playwright is not installed (the [dev] extra): pip install playwright (no browser download)")
    return exe, sync_playwright


@pytest.mark.tools
def test_html_plays_with_sound_in_headless_chromium(clip, tmp_path):
    """Open the page from file://, press Play: the audio clock advances, the morph weights and the pixels change,
    the lips follow the audio clock, the scrub bar seeks; no request leaves the page. Screenshot in runs/."""
    exe, sync_playwright = _chromium()
    verts, template, faces, wave = clip
    write_gltf(tmp_path / "a.glb", verts, faces, template)
    page_path = write_html(tmp_path / "animation.html", tmp_path / "a.glb", wave)
    shots = Path(os.environ.get("DTL_SCREENSHOTS", ROOT / "runs" / "screenshots"))
    shots.mkdir(parents=True, exist_ok=True)
    viewer = "Object.values(window.dtlViewers)[0]"
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=exe, args=[
            "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader"])
        try:
            page = browser.new_page(viewport={"width": 800, "height": 600})
            requests = []
            page.on("request", lambda r: requests.append(r.url))
            page.goto(page_path.as_uri())
            page.wait_for_function(f"() => window.dtlViewers && ({viewer}.ready || {viewer}.error)", timeout=60000)
            assert page.evaluate(f"() => {viewer}.error") is None
            before = page.evaluate(f"() => Array.from({viewer}.mesh.morphTargetInfluences)")
            pixels_before = page.locator("canvas").screenshot()
            page.click("button.play")
            page.wait_for_function(f"() => {viewer}.audio.currentTime > 1.5", timeout=20000)
            state = page.evaluate(f"""() => {{ const v = {viewer};
                return [v.audio.paused, v.audio.currentTime, v.action.time,
                        Array.from(v.mesh.morphTargetInfluences),
                        document.querySelector('button.play').textContent]; }}""")
            page.screenshot(path=str(shots / "viewer_playing.png"))
            pixels_after = page.locator("canvas").screenshot()
            paused, t_audio, t_mixer, after, label = state
            assert not paused and label == "Pause" and t_audio > 1.5
            assert abs(t_mixer - t_audio) < 0.1  # the lips follow the audio clock
            assert max(abs(a - b) for a, b in zip(before, after)) > 0.05  # the mesh moves
            assert pixels_before != pixels_after
            page.click("button.play")  # pause, then scrub to 5 s, to the end and back to 5 s
            scrub = ("(t) => { const s = document.querySelector('.scrub'); s.value = t; "
                     "s.dispatchEvent(new Event('input')); "
                     f"return [{viewer}.audio.currentTime, {viewer}.action.time, "
                     f"Array.from({viewer}.mesh.morphTargetInfluences)]; }}")
            t_audio, t_action, at5 = page.evaluate(scrub, 5)
            assert abs(t_audio - 5) < 0.05 and abs(t_action - 5) < 1e-6
            end = page.evaluate(scrub, len(verts) / 30)[2]
            again = page.evaluate(scrub, 5)[2]  # a finished animation still follows the scrub bar back
            assert again == at5 and max(abs(a - b) for a, b in zip(end, at5)) > 0.05
        finally:
            browser.close()
    assert [u for u in requests if not u.startswith("data:")] == [page_path.as_uri()]


# ------------------------------------------------------------------------------------------ the animate command
@pytest.fixture(scope="module")
def checkpoint(corpus, tmp_path_factory):
    """A self-describing checkpoint of an untrained tiny DualTalker (its output still moves a little)."""
    import torch

    from dualtalker_lite.checkpoints import save_checkpoint
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160, n_speakers=8)
    path = tmp_path_factory.mktemp("ckpt") / "model.pt"
    save_checkpoint(path, DualTalker(cfg).eval(), cfg, speakers=corpus.train_speakers, faces=corpus.faces)
    return path


def test_animate_writes_npy_gltf_and_html(checkpoint, corpus, tmp_path, capsys):
    from dualtalker_lite.cli import animate_main as main

    wav = sample_path() / "audio" / "SPK09_s02.flac"
    out = tmp_path / "me"
    main([str(a) for a in ["--checkpoint", checkpoint, "--wav", wav, "--speaker", "SPK01", "--out", out,
                           "--format", "npy,gltf,html"]])
    assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "animation.glb", "animation.html", "animation.wav",
                                                     "frame0.obj", "vertices.npy"]
    printed = capsys.readouterr().out
    assert "animation.glb:" in printed and "max vertex error" in printed
    verts = np.load(out / "vertices.npy")
    got = read_gltf_animation(out / "animation.glb")
    np.testing.assert_array_equal(got["base"].reshape(-1), corpus.template("SPK01"))  # the rest shape
    rec = got["base"].reshape(-1) + got["weights"] @ got["targets"].reshape(len(got["targets"]), -1)
    assert _vertex_error(rec, verts).max() < 1e-4 and len(got["times"]) == len(verts)
    glb64 = base64.b64encode((out / "animation.glb").read_bytes()).decode()
    assert f'const GLB = "{glb64}"' in (out / "animation.html").read_text()  # the page plays that very file
    only = tmp_path / "page"  # html alone: no .glb or .wav left beside it
    main([str(a) for a in ["--checkpoint", checkpoint, "--wav", wav, "--out", only, "--format", "html"]])
    assert sorted(p.name for p in only.iterdir()) == [".dualtalker-output.json", "animation.html"]
