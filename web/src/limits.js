/**
 * Resource limits enforced on untrusted input (spec section 9, [R-60]..[R-62]).
 *
 * Every count or length a file declares is checked against these before anything sized from it is
 * allocated. The defaults are the values of the spec, which conformance is judged under ([R-60]);
 * a caller may choose others.
 */
import { SpcError } from './errors.js';

const MIB = 2 ** 20;
const GIB = 2 ** 30;

/**
 * @typedef {object} Limits
 * @property {number} maxFileBytes largest inner (un-gzipped) file, bytes
 * @property {number} maxGaussians largest total Gaussian count
 * @property {number} maxLayers largest layer count
 * @property {number} maxSections largest section count
 * @property {number} maxClusters largest sketch cluster count
 * @property {number} maxSectionBytes largest raw length of one section
 * @property {number} maxMetadataBytes largest metadata raw length
 * @property {number} maxExpansionRatio raw bytes per file byte allowed above the floor ([R-61])
 * @property {number} expansionFloorBytes raw bytes always allowed
 * @property {number} maxGaussiansPerByte Gaussians per file byte allowed above the floor ([R-61])
 * @property {number} gaussianFloor Gaussians always allowed
 */

/** @type {Readonly<Limits>} */
export const DEFAULT_LIMITS = Object.freeze({
  maxFileBytes: 4 * GIB,
  maxGaussians: 64_000_000,
  maxLayers: 1024,
  maxSections: 4096,
  maxClusters: 4_000_000,
  maxSectionBytes: 2 * GIB,
  maxMetadataBytes: 16 * MIB,
  maxExpansionRatio: 1024,
  expansionFloorBytes: 64 * MIB,
  maxGaussiansPerByte: 64,
  gaussianFloor: 1_000_000,
});

/**
 * The defaults with the caller's overrides.
 * @param {Partial<Limits>} [overrides]
 * @returns {Readonly<Limits>}
 */
export function resolveLimits(overrides) {
  return overrides ? Object.freeze({ ...DEFAULT_LIMITS, ...overrides }) : DEFAULT_LIMITS;
}

/**
 * @param {string} what
 * @param {number} value
 * @param {number} limit
 */
export function checkLimit(what, value, limit) {
  if (value > limit) {
    throw new SpcError('limit-exceeded', `${what} is ${value}, above the limit of ${limit}`);
  }
}

/**
 * A file may not declare far more Gaussians than its size can carry ([R-61]).
 * @param {Limits} limits
 * @param {number} gaussians
 * @param {number} fileBytes
 */
export function checkGaussianDensity(limits, gaussians, fileBytes) {
  const allowed = Math.max(limits.gaussianFloor, Math.floor(limits.maxGaussiansPerByte * fileBytes));
  if (gaussians > allowed) {
    throw new SpcError('limit-exceeded', `a ${fileBytes}-byte file declares ${gaussians} Gaussians ` +
      `(more than ${limits.maxGaussiansPerByte} per byte)`);
  }
}

/**
 * The raw lengths of all sections may not exceed max(floor, ratio x file size) ([R-61]).
 * @param {Limits} limits
 * @param {number} rawTotal
 * @param {number} fileBytes
 */
export function checkExpansion(limits, rawTotal, fileBytes) {
  const allowed = Math.max(limits.expansionFloorBytes, Math.floor(limits.maxExpansionRatio * fileBytes));
  if (rawTotal > allowed) {
    throw new SpcError('limit-exceeded', `sections declare ${rawTotal} raw bytes for a ` +
      `${fileBytes}-byte file (more than ${limits.maxExpansionRatio}x expansion)`);
  }
}
