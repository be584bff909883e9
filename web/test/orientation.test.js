// Standing a scene upright: the rotation from its up axis to +Y, and positions turned by it.

import assert from 'node:assert/strict';
import test from 'node:test';

import { rotatePositions, upRotation } from '../src/orientation.js';

test('upRotation stands every axis upright, as the glTF writer does, and rotates rigidly', () => {
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
