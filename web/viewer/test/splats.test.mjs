// The decoder's layout to PLY-named columns, and the default framing.

import assert from 'node:assert/strict';
import test from 'node:test';
import { plyProperties } from '../../loaders/playcanvas.js';
import { rotatePositions } from '../../src/orientation.js';
import { SceneFraming, frameBounds, metadataBounds, robustBounds, turnBounds } from '../src/splats.js';

test('plyProperties splits interleaved arrays and writes f_rest channel-major', () => {
  const n = 2, shDegree = 1, k = 3;
  const shRest = new Float32Array(n * k * 3);
  for (let i = 0; i < n; i++) for (let c = 0; c < k; c++) for (let ch = 0; ch < 3; ch++) {
    shRest[(i * k + c) * 3 + ch] = 100 * i + 10 * c + ch;  // Gaussian i, coefficient c, channel ch
  }
  const props = plyProperties({
    count: n, shDegree,
    positions: Float32Array.of(1, 2, 3, 4, 5, 6), scales: Float32Array.of(-1, -2, -3, -4, -5, -6),
    rotations: Float32Array.of(1, 0, 0, 0, 0.5, 0.5, 0.5, 0.5), opacities: Float32Array.of(0.25, -2),
    shDC: Float32Array.of(7, 8, 9, 10, 11, 12), shRest,
  });
  assert.deepEqual([...props.get('y')], [2, 5]);
  assert.deepEqual([...props.get('scale_2')], [-3, -6]);
  assert.deepEqual([...props.get('rot_0')], [1, 0.5]);
  assert.deepEqual([...props.get('opacity')], [0.25, -2]);
  assert.deepEqual([...props.get('f_dc_1')], [8, 11]);
  // PLY f_rest_(channel * K + coefficient), as the INRIA layout and the Python PLY writer have it
  assert.deepEqual([...props.get('f_rest_0')], [0, 100]);     // R, c1
  assert.deepEqual([...props.get('f_rest_2')], [20, 120]);    // R, c3
  assert.deepEqual([...props.get('f_rest_3')], [1, 101]);     // G, c1
  assert.deepEqual([...props.get('f_rest_8')], [22, 122]);    // B, c3
  assert.equal(props.size, 3 + 3 + 1 + 3 + 4 + 9);
});

test('robustBounds ignores a far floater and frameBounds looks at the centre from outside', () => {
  const n = 1000;
  const positions = new Float32Array(n * 3);
  for (let i = 0; i < n; i++) positions.set([(i % 10) / 10, Math.floor(i / 10) % 10 / 10, i / n], i * 3);
  positions.set([1e6, 1e6, 1e6], 0);
  const bounds = robustBounds(positions);
  assert.ok(bounds.radius < 2, `radius ${bounds.radius}`);
  const view = frameBounds(bounds, [0, -1, 0], 50);
  const distance = Math.hypot(...view.position.map((p, i) => p - view.target[i]));
  assert.ok(distance > bounds.radius);
  assert.ok(view.position[1] < view.target[1], 'above the centre means smaller y when -y is up');
  assert.equal(robustBounds(new Float32Array(0)), null);
});

/** `n` centres spread evenly through the box [lo, hi] (a seeded LCG, so runs agree). */
function boxOf(n, lo, hi, seed = 1) {
  let x = seed;
  const next = () => ((x = (x * 1664525 + 1013904223) >>> 0) / 2 ** 32);
  const out = new Float32Array(3 * n);
  for (let i = 0; i < 3 * n; i++) out[i] = lo[i % 3] + next() * (hi[i % 3] - lo[i % 3]);
  return out;
}

/** The share of `positions` in front of the camera and inside its field of view (a square image:
 * the vertical field of view both ways). */
function framedShare(view, positions) {
  const sub = (a, b) => a.map((v, i) => v - b[i]);
  const unit = (v) => v.map((x) => x / Math.hypot(...v));
  const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
  const dot = (a, b) => a.reduce((s, v, i) => s + v * b[i], 0);
  const forward = unit(sub(view.target, view.position));
  const right = unit(cross(forward, view.up));
  const up = cross(right, forward);
  const half = Math.tan((view.fov * Math.PI / 180) / 2);
  let inside = 0;
  const n = positions.length / 3;
  for (let i = 0; i < n; i++) {
    const d = sub([...positions.subarray(3 * i, 3 * i + 3)], view.position);
    const z = dot(d, forward);
    if (z > 0 && Math.abs(dot(d, right)) <= half * z && Math.abs(dot(d, up)) <= half * z) inside++;
  }
  return inside / n;
}

test('SceneFraming frames the whole scene when layer 0 holds one corner of it', () => {
  const corner = boxOf(1025, [0, 0, 0], [1, 1, 1]);  // layer 0: a corner of the 10 m box
  const rest = [boxOf(30000, [0, 0, 0], [10, 10, 10], 2), boxOf(60000, [0, 0, 0], [10, 10, 10], 3)];
  const whole = new Float32Array([...corner, ...rest[0], ...rest[1]]);
  const framing = new SceneFraming();
  const first = framing.add(corner);
  assert.ok(first && first.radius < 1, 'layer 0 is framed first');
  assert.ok(framedShare(frameBounds(first), whole) < 0.1, 'layer 0 alone frames a sliver of it');
  const next = framing.add(rest[0]);
  assert.ok(next, 'a layer reaching out of the view frames the scene again');
  assert.ok(framedShare(frameBounds(next), whole) > 0.95);
  assert.equal(framing.add(rest[1]), null, 'more of the same scene leaves the camera where it is');
  assert.ok(framing.samples.length <= 3 * 40000 && framing.stride > 1, 'the sample stays small');
});

test('SceneFraming keeps the framing of a preview of the whole scene, and samples in world space', () => {
  const framing = new SceneFraming();
  const preview = boxOf(500, [-5, -5, -5], [5, 5, 5]);
  assert.ok(framing.add(preview));
  assert.equal(framing.add(boxOf(2000, [-1, -1, -1], [1, 1, 1])), null, 'inside the view');
  assert.equal(framing.add(boxOf(2000, [-5, -5, -5], [5.3, 5, 5])), null, 'within the slack');
  const moved = new SceneFraming().add(preview, (p) => p.map((v, i) => (i % 3 === 1 ? v + 100 : v)));
  assert.ok(Math.abs(moved.centre[1] - 100) < 1, 'toWorld turns the sampled centres');
  assert.equal(new SceneFraming().add(new Float32Array(0)), null);
});

test('metadataBounds reads the robust box of the metadata, else its full box, and nothing malformed', () => {
  const robust = metadataBounds({ bounds: { min: [-100, -1, -1], max: [100, 1, 1],
    robust: { min: [0, 0, 0], max: [2, 4, 4], percentiles: [2, 98] } } });
  assert.deepEqual(robust.centre, [1, 2, 2]);
  assert.equal(robust.radius, 3);  // half the diagonal of 2 x 4 x 4
  const full = metadataBounds({ bounds: { min: [0, 0, 0], max: [0, 6, 8] } });
  assert.deepEqual(full, { centre: [0, 3, 4], radius: 5 });
  for (const bad of [null, {}, { bounds: 7 }, { bounds: { min: [0, 0], max: [1, 1] } },
    { bounds: { min: [0, 0, 0], max: [1, 'a', 1] } }, { bounds: { min: [2, 0, 0], max: [1, 1, 1] } },
    { bounds: { robust: { min: [0, 0, 0], max: [1, 1, Infinity] } } }]) {
    assert.equal(metadataBounds(bad), null, JSON.stringify(bad));
  }
  const point = metadataBounds({ bounds: { min: [1, 1, 1], max: [1, 1, 1] } });
  assert.ok(point.radius > 0, 'a point still gives a camera distance');
});

test('the metadata box frames the whole scene from layer 0, turned upright by the file\'s rotation', () => {
  const whole = boxOf(20000, [0, 0, 0], [10, 10, 10], 4);
  const lo = [0, 1, 2].map((a) => Math.min(...whole.filter((_, i) => i % 3 === a)));
  const hi = [0, 1, 2].map((a) => Math.max(...whole.filter((_, i) => i % 3 === a)));
  const bounds = metadataBounds({ bounds: { min: lo, max: hi } });
  assert.ok(framedShare(frameBounds(bounds), whole) > 0.95);
  const zUp = [-Math.SQRT1_2, 0, 0, Math.SQRT1_2];  // +Z to +Y: a quarter turn about -X
  const turned = turnBounds(bounds, zUp);
  assert.equal(turned.radius, bounds.radius);
  const expected = [...rotatePositions(Float32Array.from(bounds.centre), zUp)];
  turned.centre.forEach((c, i) => assert.ok(Math.abs(c - expected[i]) < 1e-5));
  assert.ok(framedShare(frameBounds(turned), rotatePositions(whole, zUp)) > 0.95);
  assert.equal(turnBounds(bounds, null), bounds);
});
