/**
 * Draco point clouds (sketch positions, patch positions in mode 3) through the
 * draco3d WebAssembly decoder, with the header checks of first.
 *
 * After decoding, the blob must hold one attribute, POSITION with 3 float32 components (Draco
 * decodes a GENERIC or int8 attribute without complaint).
 *
 * The Draco library sizes buffers from its own header before it finds out that a blob is short,
 * so a blob is refused unless it is a point cloud in bitstream 2.3, without Draco metadata,
 * declaring exactly the expected number of points. A WebAssembly abort (out of memory, say)
 * leaves the module unusable, so after any exception from it the module is dropped and a fresh one
 * is instantiated for the next blob.
 */
import { SpcError } from './errors.js';

/**
 * The parts of the draco3d decoder module used here.
 * @typedef {any} DracoModule
 */

/** @type {Promise<DracoModule> | null} */
let modulePromise = null;
/** @type {(() => Promise<DracoModule>) | null} */
let factory = null;

/**
 * Choose how the Draco decoder module is created, e.g. in a browser
 * `configureDraco(() => createDecoderModule({ wasmBinary }))`. By default the `draco3d` package's
 * `createDecoderModule({})` is used.
 * @param {() => Promise<DracoModule>} create
 */
export function configureDraco(create) {
  factory = create;
  modulePromise = null;
}

/** @returns {Promise<DracoModule>} */
async function defaultFactory() {
  const draco3d = await import('draco3d');
  return (draco3d.default ?? draco3d).createDecoderModule({});
}

/**
 * The Draco decoder module, instantiated once.
 * @returns {Promise<DracoModule>}
 */
export function loadDraco() {
  if (!modulePromise) {
    modulePromise = (factory ?? defaultFactory)();
    modulePromise.catch(() => { modulePromise = null; });
  }
  return modulePromise;
}

/**
 * @param {string} message
 * @returns {never}
 */
function dracoFailed(message) {
  throw new SpcError('draco-failed', message);
}

/**
 * The fixed header checks of.
 * @param {Uint8Array} blob
 * @param {number} count points the file declares for the blob
 * @param {string} what names the blob in messages
 */
export function checkDracoHeader(blob, count, what) {
  if (blob.length < 15 || String.fromCharCode(...blob.subarray(0, 5)) !== 'DRACO') {
    dracoFailed(`${what}: not a Draco blob`);
  }
  if (blob[7] !== 0) dracoFailed(`${what}: Draco blob is not a point cloud (type ${blob[7]})`);
  if (blob[5] !== 2 || blob[6] !== 3 || blob[8] > 1) {
    dracoFailed(`${what}: Draco bitstream ${blob[5]}.${blob[6]}, method ${blob[8]} is not supported`);
  }
  if (blob[10] & 0x80) dracoFailed(`${what}: Draco metadata is not supported`);
  const declared = blob[11] | (blob[12] << 8) | (blob[13] << 16) | (blob[14] << 24);
  if (declared !== count) dracoFailed(`${what}: Draco blob declares ${declared} points, expected ${count}`);
}

/**
 * Decode a Draco point cloud that must hold exactly `count` finite points, in decode order.
 * @param {DracoModule} M the module from {@link loadDraco}
 * @param {Uint8Array} blob
 * @param {number} count
 * @param {string} what
 * @returns {Float32Array} xyz of each point
 */
export function decodePoints(M, blob, count, what) {
  checkDracoHeader(blob, count, what);
  let decoder = null;
  let cloud = null;
  let ptr = 0;
  try {
    decoder = new M.Decoder();
    cloud = new M.PointCloud();
    const status = decoder.DecodeArrayToPointCloud(blob, blob.length, cloud);
    if (!status.ok()) dracoFailed(`${what}: Draco blob cannot be decoded (${status.error_msg()})`);
    if (cloud.num_attributes() !== 1) dracoFailed(`${what}: Draco blob carries attributes besides positions`);
    const id = decoder.GetAttributeId(cloud, M.POSITION);
    if (id < 0) dracoFailed(`${what}: Draco blob has no positions`);
    const attribute = decoder.GetAttribute(cloud, id);
    if (attribute.num_components() !== 3 || attribute.data_type() !== M.DT_FLOAT32) {
      dracoFailed(`${what}: the Draco attribute is not POSITION with 3 float32 components`);
    }
    const n = cloud.num_points();
    if (n !== count) dracoFailed(`${what}: Draco blob holds ${n} points, expected ${count}`);
    const bytes = n * 12;
    const points = new Float32Array(n * 3);
    if (n > 0) {
      ptr = M._malloc(bytes);
      if (!ptr) dracoFailed(`${what}: the Draco decoder cannot hold ${n} points`);
      if (!decoder.GetAttributeDataArrayForAllPoints(cloud, attribute, M.DT_FLOAT32, bytes, ptr)) {
        dracoFailed(`${what}: Draco positions cannot be read`);
      }
      points.set(new Float32Array(M.HEAPF32.buffer, ptr, n * 3));
    }
    for (let i = 0; i < points.length; i++) {
      if (!Number.isFinite(points[i])) dracoFailed(`${what}: Draco positions are not finite`);
    }
    return points;
  } catch (err) {
    if (err instanceof SpcError) throw err;
    modulePromise = null; // an aborted WebAssembly instance cannot be trusted again
    return dracoFailed(`${what}: the Draco decoder failed (${err instanceof Error ? err.message : String(err)})`);
  } finally {
    try {
      if (ptr) M._free(ptr);
      if (cloud) M.destroy(cloud);
      if (decoder) M.destroy(decoder);
    } catch {
      modulePromise = null;
    }
  }
}
