// The live page's second head: a stylised head made of three.js primitives, driven only by the 15 standard viseme
// curves (viseme_sil, viseme_PP, ...) the server streams, as any Oculus / Ready Player Me style avatar would be.
// The weights are first turned into the rig's mouth controls, c_k = sum_v w_v T_vk (T: the /mesh document's
// `avatar.targets`, the rig's target of each viseme, export/visemes.rig_viseme_targets), and the controls into
// this head's shapes by mouthShape below (the mapping is documented in docs/live.md). Nothing is loaded: no mesh
// file, no texture, no network.
import * as THREE from 'three';
import { litScene } from 'dualtalker-lite/scene.js';

// rig mouth controls {jaw_open, lip_press, ...} -> this head's mouth (head radius = 1):
//   gap:     lips apart         0.02 + 0.5 x clamp(jaw_open + 0.3 lower_lip_depress + 0.2 upper_lip_raise
//                                                  - 0.6 lip_press, 0, 1)           (0.02: lips at rest)
//   width:   mouth width        0.5 x clamp(1 + 0.4 lip_stretch + 0.25 (smile_left + smile_right) - 0.5 lip_pucker,
//                                           0.45, 1.6)
//   forward: lips pushed out    0.12 x max(lip_pucker, 0)
//   press:   lips flattened     clamp(lip_press, 0, 1) (their thickness x (1 - 0.4 press))
//   jaw:     chin drop          0.25 x max(jaw_open, 0)
export function mouthShape(c) {
  const g = (k) => c[k] || 0;
  const clamp = (x, lo, hi) => Math.min(hi, Math.max(lo, x));
  const open = clamp(g('jaw_open') + 0.3 * g('lower_lip_depress') + 0.2 * g('upper_lip_raise')
                     - 0.6 * g('lip_press'), 0, 1);
  return {
    gap: 0.02 + 0.5 * open,
    width: 0.5 * clamp(1 + 0.4 * g('lip_stretch') + 0.25 * (g('smile_left') + g('smile_right'))
                       - 0.5 * g('lip_pucker'), 0.45, 1.6),
    forward: 0.12 * Math.max(g('lip_pucker'), 0),
    press: clamp(g('lip_press'), 0, 1),
    jaw: 0.25 * Math.max(g('jaw_open'), 0),
  };
}

// The head's sizes (head radius = 1): the skull is an egg of these radii about the origin, the mouth sits at MOUTH,
// each lip is a capsule of radius LIP_R (times its thickness) along x. The upper lip rises by half the gap as the
// mouth opens, where the egg bulges forward: it rides on the egg's front (skullFront at the lip's top edge, on the
// mid-line, where the egg reaches farthest) so that it never sinks into the head (it did at wide openings). The
// lower lip and the mouth's inside keep the lips' depth at rest, the inside just behind the upper lip.
export const SKULL = [0.85, 1.05, 0.9], MOUTH = [0, -0.42, 0.8], LIP_R = 0.055;
export const skullFront = (y) => SKULL[2] * Math.sqrt(Math.max(0, 1 - (y / SKULL[1]) ** 2));

// mouthShape's result -> where the lips and the inside go, in the mouth's coordinates (MOUTH is its origin)
export function lipPlacement(s) {
  const thick = 1 - 0.4 * s.press;
  const up = s.gap / 2 + 0.04 * thick;
  const onSkull = (y) => skullFront(MOUTH[1] + y + LIP_R * thick) + 0.005 - MOUTH[2];  // the top edge just outside
  const rest = onSkull(0.02 / 2 + 0.04 * thick);                                         // mouthShape's rest gap 0.02
  const upperZ = Math.max(rest, onSkull(up)) + s.forward;
  return { thick, upper: [0, up, upperZ], lower: [0, -up - s.jaw * 0.5, rest + s.forward],
           inside: upperZ - 0.03 };
}

// viseme weights (15, in `spec.names` order) -> the rig's mouth controls {name: value}
export function controlsOf(weights, spec) {
  const c = {};
  spec.controls.forEach((name, k) => {
    let s = 0;
    for (let v = 0; v < weights.length; v++) s += weights[v] * spec.targets[v][k];
    c[name] = s;
  });
  return c;
}

export function makeAvatar(spec) {
  // lit as the mesh is (export/page/scene.js's litScene), with values of its own: a lighter background and ground
  const scene = litScene({ background: 0x2a2d31, ground: 0x404040, sky: 1.3, sun: 1.5, sunAt: [0.6, 1, 2] });
  const mat = (color, rough = 0.6) => new THREE.MeshStandardMaterial({ color, roughness: rough });
  const ball = (r, material, x, y, z, sx = 1, sy = 1, sz = 1) => {
    const m = new THREE.Mesh(new THREE.SphereGeometry(r, 40, 24), material);
    m.position.set(x, y, z); m.scale.set(sx, sy, sz);
    return m;
  };
  const head = new THREE.Group();
  const skin = mat(0x7fb8d8);
  const skull = ball(1, skin, 0, 0, 0, ...SKULL);                        // the skull: an egg
  head.add(skull);
  head.add(ball(0.16, skin, -0.84, 0.02, 0), ball(0.16, skin, 0.84, 0.02, 0));   // ears
  for (const x of [-0.3, 0.3]) {
    head.add(ball(0.15, mat(0xffffff, 0.3), x, 0.28, 0.72));             // eyes
    head.add(ball(0.065, mat(0x202020, 0.2), x, 0.28, 0.86));            // pupils
    const brow = new THREE.Mesh(new THREE.BoxGeometry(0.26, 0.045, 0.05), mat(0x2f4f66));
    brow.position.set(x, 0.5, 0.76); head.add(brow);
  }
  head.add(ball(0.11, mat(0x6aa2c4), 0, 0.02, 0.9, 1, 1.2, 1));           // nose
  const chin = ball(0.3, skin, 0, -0.74, 0.48, 1.1, 0.7, 0.8);            // moves down with jaw_open
  head.add(chin);
  const mouth = new THREE.Group();
  mouth.position.set(...MOUTH);
  const cavity = ball(1, mat(0x3a0d12, 0.9), 0, 0, -0.03);                 // the dark inside, scaled per frame
  const lip = () => {
    const m = new THREE.Mesh(new THREE.CapsuleGeometry(LIP_R, 1, 6, 16), mat(0xc4505a, 0.45));
    m.rotation.z = Math.PI / 2;                                            // along x
    return m;
  };
  const upper = lip(), lower = lip();
  mouth.add(cavity, upper, lower);
  head.add(mouth);
  scene.add(head);
  const camera = new THREE.PerspectiveCamera(30, 1, 0.1, 50);
  camera.position.set(0, -0.05, 5.2);
  camera.lookAt(0, -0.05, 0);

  const pose = (c) => {
    const s = mouthShape(c), at = lipPlacement(s);
    for (const [m, where] of [[upper, at.upper], [lower, at.lower]]) {
      m.scale.set(at.thick, s.width, at.thick);                           // capsule along x: its y is the length
      m.position.set(...where);
    }
    cavity.scale.set(s.width * 0.5, (s.gap + s.jaw * 0.5) / 2 + 0.01, 0.08);
    cavity.position.set(0, -s.jaw * 0.25, at.inside);
    chin.position.y = -0.74 - s.jaw;
    return s;
  };
  const rest = pose({});
  const fit = (aspect) => {   // the whole head (2.2 wide with the ears, 2.6 tall) in a 30 degree view
    camera.aspect = aspect;
    camera.position.z = Math.max(5.2, 4.3 / aspect);
    camera.updateProjectionMatrix();
  };
  return { scene, camera, rest, fit, update: (weights) => pose(controlsOf(weights, spec)), pose,
           parts: { head, skull, upper, lower } };
}
