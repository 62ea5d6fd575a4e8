"""The live page's stylised head (``live/page/avatar.js``) as three.js builds it, in node: at every mouth opening,
up to the widest, the upper lip's front stays outside the head (it sank into the egg-shaped skull at wide openings,
6 of 32 screenshots), and the lips keep their order. The geometry is the page's own: node runs avatar.js against the
vendored three.js and reads back the transformed vertices; the skull is tested as the ellipsoid its mesh is."""
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from dualtalker_lite.export.html import page_dir, vendor_dir
from dualtalker_lite.live.server import PAGE_DIR

pytestmark = pytest.mark.tools

SCRIPT = r"""
import * as THREE from 'three';
import { makeAvatar, SKULL } from './avatar.js';
// one viseme, "aa" (the widest), pushed past any real weight: jaw_open x 3 saturates the opening (clamp at 1)
const spec = { names: ['viseme_sil', 'viseme_aa'], controls: ['jaw_open', 'lip_press'], targets: [[0, 0], [3, 0]] };
const avatar = makeAvatar(spec);
const { head, skull, upper, lower } = avatar.parts;
const out = [];
for (const w of [0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.7, 1]) {
  const s = avatar.update([1 - w, w]);
  avatar.scene.updateMatrixWorld(true);
  const toHead = new THREE.Matrix4().copy(head.matrixWorld).invert();
  const points = (m) => {
    const p = m.geometry.attributes.position, v = new THREE.Vector3(), all = [];
    for (let i = 0; i < p.count; i++) {
      all.push(v.fromBufferAttribute(p, i).applyMatrix4(m.matrixWorld).applyMatrix4(toHead).toArray());
    }
    return all;
  };
  const centre = (m) => new THREE.Vector3().setFromMatrixPosition(m.matrixWorld).applyMatrix4(toHead).toArray();
  out.push({ w, gap: s.gap, upper: points(upper), upperCentre: centre(upper), lowerCentre: centre(lower),
             skullScale: skull.scale.toArray(), skullAt: skull.position.toArray(), SKULL });
}
console.log(JSON.stringify(out));
"""


def run_avatar(tmp_path: Path) -> list[dict]:
    node = shutil.which("node")
    if node is None:
        if os.environ.get("DUALTALKER_REQUIRE_EXPORT_TOOLS"):
            pytest.fail("DUALTALKER_REQUIRE_EXPORT_TOOLS is set but node is not installed")
        pytest.skip("node is not installed (node >= 18; make test-tools says how)")
    # the page's bare imports ('three', 'three/addons/...', 'dualtalker-lite/scene.js'), as its import map names them
    three = tmp_path / "node_modules" / "three"
    (three / "addons" / "controls").mkdir(parents=True)
    shutil.copy(vendor_dir() / "three.module.min.js", three / "three.module.min.js")
    shutil.copy(vendor_dir() / "OrbitControls.js", three / "addons" / "controls" / "OrbitControls.js")
    (three / "package.json").write_text(json.dumps({"name": "three", "type": "module", "exports": {
        ".": "./three.module.min.js", "./addons/*": "./addons/*"}}))
    stage = tmp_path / "node_modules" / "dualtalker-lite"
    stage.mkdir()
    shutil.copy(page_dir() / "scene.js", stage / "scene.js")
    (stage / "package.json").write_text(json.dumps({"name": "dualtalker-lite", "type": "module",
                                                    "exports": {"./scene.js": "./scene.js"}}))
    shutil.copy(PAGE_DIR / "avatar.js", tmp_path / "avatar.js")
    (tmp_path / "package.json").write_text('{"type": "module"}')
    (tmp_path / "check.js").write_text(SCRIPT)
    proc = subprocess.run([node, "check.js"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout)


def test_the_upper_lip_stays_outside_the_head_at_every_opening(tmp_path):
    frames = run_avatar(tmp_path)
    assert frames[0]["gap"] == pytest.approx(0.02) and frames[-1]["gap"] == pytest.approx(0.52)  # rest .. widest
    for f in frames:
        assert f["skullScale"] == f["SKULL"] and f["skullAt"] == [0, 0, 0]  # the egg: x²/a² + y²/b² + z²/c² = 1
        a, b, c = f["SKULL"]
        zc = f["upperCentre"][2]
        front = [(x, y, z) for x, y, z in f["upper"] if z >= zc]  # the half of the lip that faces the camera
        inside = [(x, y, z) for x, y, z in front if (x / a) ** 2 + (y / b) ** 2 + (z / c) ** 2 <= 1]
        assert len(front) > 100 and not inside, (f["w"], f["gap"], len(inside), inside[:3])
        assert f["upperCentre"][1] - f["lowerCentre"][1] >= f["gap"]  # the lips stay apart by the gap, in order
