// An .spc inside a binary glTF: `spcodec embed` writes a .glb whose KHR_gaussian_splatting
// primitive carries the .spc in a buffer view named by the vendor extension
// SPCODEC_gaussian_splatting_compression_spc (as KHR_gaussian_splatting_compression_spz_2 does
// for SPZ). This finds where those bytes lie in the file and how the node turns the scene, from
// the GLB header and JSON chunk alone, so a loader can stream the .spc with range requests.


export const GLB_MAGIC = 0x46546c67;  // "glTF"
export const SPLATS = 'KHR_gaussian_splatting';
export const COMPRESSION = 'SPCODEC_gaussian_splatting_compression_spc';
const CHUNK_JSON = 0x4e4f534a;
const CHUNK_BIN = 0x004e4942;

/** Bytes of a .glb that hold its 12-byte header and the JSON chunk's 8-byte header: what to fetch
 * first to learn the JSON chunk's length. */
export const GLB_PREAMBLE_BYTES = 20;

/**
 * Whether `head` (the first bytes of a file) starts a binary glTF.
 * @param {Uint8Array} head
 */
export function isGlb(head) {
  return head.length >= 4 && new DataView(head.buffer, head.byteOffset, 4).getUint32(0, true) === GLB_MAGIC;
}

/**
 * Where the embedded .spc lies in a .glb, from the file's first bytes (at least the header and
 * the whole JSON chunk; `jsonEnd(head)` says how many).
 * @param {Uint8Array} head
 * @returns {{offset: number, length: number, rotation: number[]|null, document: object}}
 *   byte offset and length of the .spc in the file, and the node's rotation (x, y, z, w)
 */
export function locateSpc(head) {
  if (!isGlb(head) || head.length < GLB_PREAMBLE_BYTES) fail('not a binary glTF (.glb) file');
  const view = new DataView(head.buffer, head.byteOffset, head.byteLength);
  const jsonLength = view.getUint32(12, true);
  if (view.getUint32(16, true) !== CHUNK_JSON) fail('the first chunk of the .glb is not JSON');
  const end = GLB_PREAMBLE_BYTES + jsonLength;
  if (head.length < end + 8) fail('the .glb ends inside its JSON chunk');
  let document;
  try {
    document = JSON.parse(new TextDecoder().decode(head.subarray(GLB_PREAMBLE_BYTES, end)));
  } catch {
    fail('the JSON chunk of the .glb is not JSON');
  }
  if (view.getUint32(end + 4, true) !== CHUNK_BIN) fail('the .glb has no binary chunk');
  const binStart = end + 8;
  for (const [n, node] of (document.nodes ?? []).entries()) {
    const mesh = document.meshes?.[node.mesh];
    for (const primitive of mesh?.primitives ?? []) {
      const spc = primitive.extensions?.[SPLATS]?.extensions?.[COMPRESSION];
      if (!spc) continue;
      const bufferView = document.bufferViews?.[spc.bufferView];
      if (!bufferView || (bufferView.buffer ?? 0) !== 0) {
        fail(`node ${n}: ${COMPRESSION} names no buffer view of the binary chunk`);
      }
      return { offset: binStart + (bufferView.byteOffset ?? 0), length: bufferView.byteLength,
        rotation: node.rotation ?? null, document };
    }
  }
  fail(`the .glb holds no ${COMPRESSION} primitive (an uncompressed glTF: open it with a glTF loader)`);
}

/**
 * How many leading bytes of a .glb hold its JSON chunk and the binary chunk's header.
 * @param {Uint8Array} preamble the first GLB_PREAMBLE_BYTES bytes
 */
export function jsonEnd(preamble) {
  if (!isGlb(preamble) || preamble.length < GLB_PREAMBLE_BYTES) fail('not a binary glTF (.glb) file');
  return GLB_PREAMBLE_BYTES + new DataView(preamble.buffer, preamble.byteOffset, 16).getUint32(12, true) + 8;
}

/** A .glb that is not one `spcodec embed` writes: a container problem, outside the .spc spec's
 * error codes (the embedded .spc's own faults are SpcError, as for a plain file). */
export class GlbError extends Error {
  constructor(message) {
    super(`${message} [bad-glb]`);
    this.name = 'GlbError';
    this.code = 'bad-glb';
  }
}

function fail(message) {
  throw new GlbError(message);
}
