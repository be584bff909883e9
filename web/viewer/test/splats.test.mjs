// The decoder's layout to PLY-named columns, and the default framing.

import assert from 'node:assert/strict';
import test from 'node:test';
import { plyProperties } from '../../loaders/playcanvas.js';
import { frameBounds, robustBounds } from '../src/splats.js';

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
