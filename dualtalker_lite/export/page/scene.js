// The three.js stage both pages draw a face on, written once: the exported viewer (export/html.py inlines this file
// into its import map as a data: URL, so the page stays one self-contained file) and the live page (live/page/live.js
// and avatar.js; the live server serves it as /page/scene.js). Both import it as 'dualtalker-lite/scene.js'.
//
//   makeStage(view)                      -> {renderer, scene, camera, controls}: a canvas in `view`, a lit scene,
//                                           a 30 degree camera that the mouse orbits (drag, wheel, right drag)
//   litScene(options)                    -> a scene with a background, a sky/ground light and one sun
//   frameBox(camera, controls, box)      look at a THREE.Box3 from 1.5 diagonals in front of it (+z)
//   fitToView(view, renderer, camera, share, after)
//                                        keep the canvas the size of `view` (the camera takes `share` of its width)
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

// The face's light: a white sky over a grey ground (a hemisphere light) and one sun above, right and in front.
// Both pages draw the project's mesh with the defaults; the live page's stylised head passes its own values.
export function litScene({ background = 0x202124, ground = 0x303030, sky = 1.2, sun = 1.6,
                           sunAt = [0.5, 1, 1.5] } = {}) {
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(background);
  scene.add(new THREE.HemisphereLight(0xffffff, ground, sky));
  const light = new THREE.DirectionalLight(0xffffff, sun);
  light.position.set(...sunAt);
  scene.add(light);
  return scene;
}

// preserveDrawingBuffer: the canvas can be read back after a frame (screenshots, the tests' pixel comparisons).
// The camera's near and far planes are placeholders until frameBox sizes them to the mesh.
export function makeStage(view) {
  const renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio);
  view.appendChild(renderer.domElement);
  const camera = new THREE.PerspectiveCamera(30, 1, 0.001, 100);
  const controls = new OrbitControls(camera, renderer.domElement);
  return { renderer, scene: litScene(), camera, controls };
}

// size = the box's diagonal: the camera stands 1.5 size in front of the centre (a face fills about half the
// height of a 30 degree view), its near/far planes at size / 100 and 100 size, and the orbit turns about the centre.
export function frameBox(camera, controls, box) {
  const center = box.getCenter(new THREE.Vector3()), size = box.getSize(new THREE.Vector3()).length();
  camera.position.copy(center).add(new THREE.Vector3(0, 0, 1.5 * size));
  camera.near = size / 100; camera.far = size * 100; camera.updateProjectionMatrix();
  controls.target.copy(center); controls.update();
}

// The canvas follows `view` (at least 200 px high); the camera's aspect is that of the `share` of the width it
// draws (1: all of it). `after(w, h)` runs after each resize (the live page fits its second head there).
export function fitToView(view, renderer, camera, share = 1, after = null) {
  const resize = () => {
    const w = view.clientWidth, h = Math.max(view.clientHeight, 200);
    renderer.setSize(w, h, false); camera.aspect = share * w / h; camera.updateProjectionMatrix();
    if (after) after(w, h);
  };
  new ResizeObserver(resize).observe(view);
  resize();
}
