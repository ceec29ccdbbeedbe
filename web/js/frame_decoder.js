// Frame decoder: the 64-byte little-endian OCTF header of a binary frame (docs/protocol.md,
// "Server → client: frames"). Pure; throws FrameError on anything malformed so a hostile or
// truncated message never reaches the image decoder.

export const FRAME_MAGIC = 'OCTF';
export const FRAME_HEADER_BYTES = 64;
export const VIEWS = ['3d', 'x', 'y', 'z'];
export const TIERS = ['interactive', 'refining', 'final', 'screenshot'];
export const FORMATS = ['image/jpeg', 'image/png'];

export class FrameError extends Error {}

// Decodes `buffer` (ArrayBuffer) into {header fields, image: Uint8Array view of the image bytes}.
export function decodeFrame(buffer) {
  if (!(buffer instanceof ArrayBuffer)) throw new FrameError('frame is not binary');
  if (buffer.byteLength < FRAME_HEADER_BYTES) {
    throw new FrameError(`frame of ${buffer.byteLength} bytes is shorter than its header`);
  }
  const dv = new DataView(buffer);
  const magic = String.fromCharCode(dv.getUint8(0), dv.getUint8(1), dv.getUint8(2), dv.getUint8(3));
  if (magic !== FRAME_MAGIC) throw new FrameError(`bad frame magic "${magic}"`);
  const version = dv.getUint16(4, true);
  if (version !== 1) throw new FrameError(`unsupported frame header version ${version}`);
  const headerBytes = dv.getUint16(6, true);
  if (headerBytes < FRAME_HEADER_BYTES || headerBytes > buffer.byteLength) {
    throw new FrameError(`bad frame header size ${headerBytes}`);
  }
  const view = dv.getUint8(24);
  const tier = dv.getUint8(25);
  const format = dv.getUint8(26);
  if (view >= VIEWS.length) throw new FrameError(`bad frame view ${view}`);
  if (tier >= TIERS.length) throw new FrameError(`bad frame tier ${tier}`);
  if (format >= FORMATS.length) throw new FrameError(`bad frame format ${format}`);
  const flags = dv.getUint8(27);
  const imageBytes = dv.getUint32(52, true);
  if (imageBytes !== buffer.byteLength - headerBytes) {
    throw new FrameError(
        `frame says ${imageBytes} image bytes, ${buffer.byteLength - headerBytes} follow`);
  }
  return {
    frameId: Number(dv.getBigUint64(8, true)),
    stateVersion: Number(dv.getBigUint64(16, true)),
    view: VIEWS[view],
    tier: TIERS[tier],
    mime: FORMATS[format],
    final: (flags & 1) !== 0,
    lossless: (flags & 2) !== 0,
    width: dv.getUint16(28, true),
    height: dv.getUint16(30, true),
    progress: dv.getFloat32(32, true),
    renderMs: dv.getFloat32(36, true),
    encodeMs: dv.getFloat32(40, true),
    lodBias: dv.getFloat32(44, true),
    screenshotId: dv.getUint32(48, true),
    imageBytes,
    image: new Uint8Array(buffer, headerBytes, imageBytes),
  };
}

// Builds a frame (tests and tools): the inverse of decodeFrame.
export function encodeFrame(f, image) {
  const buf = new ArrayBuffer(FRAME_HEADER_BYTES + image.byteLength);
  const dv = new DataView(buf);
  for (let i = 0; i < 4; ++i) dv.setUint8(i, FRAME_MAGIC.charCodeAt(i));
  dv.setUint16(4, 1, true);
  dv.setUint16(6, FRAME_HEADER_BYTES, true);
  dv.setBigUint64(8, BigInt(f.frameId), true);
  dv.setBigUint64(16, BigInt(f.stateVersion), true);
  dv.setUint8(24, VIEWS.indexOf(f.view));
  dv.setUint8(25, TIERS.indexOf(f.tier));
  dv.setUint8(26, FORMATS.indexOf(f.mime));
  dv.setUint8(27, (f.final ? 1 : 0) | (f.lossless ? 2 : 0));
  dv.setUint16(28, f.width, true);
  dv.setUint16(30, f.height, true);
  dv.setFloat32(32, f.progress, true);
  dv.setFloat32(36, f.renderMs, true);
  dv.setFloat32(40, f.encodeMs, true);
  dv.setFloat32(44, f.lodBias, true);
  dv.setUint32(48, f.screenshotId, true);
  dv.setUint32(52, image.byteLength, true);
  new Uint8Array(buf, FRAME_HEADER_BYTES).set(image);
  return buf;
}
