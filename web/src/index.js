/**
 * spcodec: a decoder for the Sketch&Patch++ 3D Gaussian Splatting bitstream, version 1
 * (spec/bitstream-v1.md).
 */
export { decode, inspect, StreamDecoder, parseMetadata } from './decoder.js';
export { SpcError, ERROR_CODES } from './errors.js';
export { DEFAULT_LIMITS } from './limits.js';
export { configureDraco } from './draco.js';
export { plyBytes } from './ply.js';
export { streamLayers } from './stream.js';
export { decodePreview, findPreview } from './preview.js';
export { upRotation, rotatePositions } from './orientation.js';
export {
  TilesetError, VIEW, parseTileset, graftSubtree, isSubtree, selectTiles, visibleTiles, coversRoot,
  cameraInTileset, boxCorners,
} from './tileset.js';
export { TilesetStream } from './tilestream.js';
