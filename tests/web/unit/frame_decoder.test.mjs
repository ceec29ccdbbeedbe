import {test} from 'node:test';
import assert from 'node:assert/strict';
import {decodeFrame, encodeFrame, FrameError, FRAME_HEADER_BYTES} from '../../../web/js/frame_decoder.js';

const header = {frameId: 42, stateVersion: 7, view: 'y', tier: 'refining', mime: 'image/png', final: false,
  lossless: true, width: 640, height: 480, progress: 0.5, renderMs: 12.25, encodeMs: 3.5, lodBias: -1,
  screenshotId: 0};

// Hand-written bytes for the layout of docs/protocol.md, independent of encodeFrame.
function handMade(imageBytes = 3) {
  const b = new Uint8Array(FRAME_HEADER_BYTES + imageBytes);
  b.set([0x4f, 0x43, 0x54, 0x46], 0);  // OCTF
  b[4] = 1; b[6] = 64;
  b[8] = 9;                      // frame id 9
  b[16] = 0x01; b[17] = 0x01;    // state version 257
  b[24] = 3; b[25] = 2; b[26] = 0; b[27] = 1;  // z, final, JPEG, flag final
  b[28] = 0x00; b[29] = 0x02;    // width 512
  b[30] = 0x00; b[31] = 0x01;    // height 256
  b.set([0, 0, 0x80, 0x3f], 32); // progress 1.0f
  b[52] = imageBytes;
  b.set([0xff, 0xd8, 0xff], 64);
  return b.buffer;
}

test('decodes the documented byte layout', () => {
  const f = decodeFrame(handMade());
  assert.equal(f.frameId, 9);
  assert.equal(f.stateVersion, 257);
  assert.equal(f.view, 'z');
  assert.equal(f.tier, 'final');
  assert.equal(f.mime, 'image/jpeg');
  assert.equal(f.final, true);
  assert.equal(f.lossless, false);
  assert.equal(f.width, 512);
  assert.equal(f.height, 256);
  assert.equal(f.progress, 1);
  assert.deepEqual([...f.image], [0xff, 0xd8, 0xff]);
});

test('round-trips every field', () => {
  const image = new Uint8Array([1, 2, 3, 4, 5]);
  const f = decodeFrame(encodeFrame(header, image));
  for (const [k, v] of Object.entries(header)) assert.equal(f[k], v, k);
  assert.deepEqual([...f.image], [...image]);
});

test('refuses malformed frames with a FrameError', () => {
  assert.throws(() => decodeFrame(new ArrayBuffer(10)), FrameError);
  assert.throws(() => decodeFrame('text'), FrameError);
  const bad = (mutate) => {
    const b = new Uint8Array(handMade());
    mutate(b);
    return b.buffer;
  };
  assert.throws(() => decodeFrame(bad((b) => { b[0] = 0x58; })), /magic/);
  assert.throws(() => decodeFrame(bad((b) => { b[4] = 2; })), /version/);
  assert.throws(() => decodeFrame(bad((b) => { b[6] = 32; })), /header size/);
  assert.throws(() => decodeFrame(bad((b) => { b[6] = 200; })), /header size/);
  assert.throws(() => decodeFrame(bad((b) => { b[24] = 4; })), /view/);
  assert.throws(() => decodeFrame(bad((b) => { b[25] = 9; })), /tier/);
  assert.throws(() => decodeFrame(bad((b) => { b[26] = 2; })), /format/);
  assert.throws(() => decodeFrame(bad((b) => { b[52] = 200; })), /image bytes/);
});

test('a larger header is skipped as the header says', () => {
  const image = new Uint8Array([7, 8]);
  const base = new Uint8Array(encodeFrame(header, image));
  const big = new Uint8Array(base.length + 16);
  big.set(base.subarray(0, 64));
  big.set(image, 80);
  new DataView(big.buffer).setUint16(6, 80, true);
  const f = decodeFrame(big.buffer);
  assert.deepEqual([...f.image], [7, 8]);
});
