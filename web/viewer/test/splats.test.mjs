// The decoder's layout to PLY-named columns, and the default framing.

import assert from 'node:assert/strict';
import test from 'node:test';
import { frameBounds, plyProperties, robustBounds } from '../src/splats.js';

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

test('upRotation stands every axis upright, as the glTF writer does, and rotates rigidly', async () => {
  const { upRotation, rotatePositions } = await import('../src/splats.js');
  const axes = { '+x': [1, 0, 0], '-x': [-1, 0, 0], '+y': [0, 1, 0], '-y': [0, -1, 0],
    '+z': [0, 0, 1], '-z': [0, 0, -1], z: [0, 0, 1] };
  for (const [name, v] of Object.entries(axes)) {
    for (const up of [name, v.join(',')]) {
      const turned = rotatePositions(Float32Array.from(v), upRotation(up));
      assert.ok(Math.abs(turned[0]) < 1e-6 && Math.abs(turned[1] - 1) < 1e-6 && Math.abs(turned[2]) < 1e-6,
        `${up} -> ${[...turned]}`);
    }
  }
  assert.deepEqual(upRotation(null), upRotation('-y'));  // files that do not say: -y
  const tilted = upRotation('0.3,0.2,0.9');
  const turned = rotatePositions(Float32Array.of(0.3, 0.2, 0.9, 1, 2, 3), tilted);
  assert.ok(Math.abs(Math.hypot(turned[0], turned[1], turned[2]) - Math.hypot(0.3, 0.2, 0.9)) < 1e-6);
  assert.ok(Math.abs(Math.hypot(turned[3], turned[4], turned[5]) - Math.hypot(1, 2, 3)) < 1e-5);
  assert.throws(() => upRotation('w'), /unknown up axis/);
});
