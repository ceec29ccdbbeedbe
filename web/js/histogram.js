// Histogram of a channel (GET /api/datasets/{id}/histogram, counts of all inserted voxels in 256
// equal bins over [lo, hi) in the file's units): percentiles for auto-contrast, the map between
// file units and the stored units windows are given in, and drawing the histogram with the
// current window over it. Pure except drawHistogram.

// Value at fraction q (0..1) of the counted voxels, linearly interpolated inside the bin.
export function percentile(channel, q) {
  const bins = channel.bins || [];
  const total = bins.reduce((a, b) => a + b, 0);
  if (total === 0) return null;
  const width = (channel.hi - channel.lo) / bins.length;
  const target = q * total;
  let cum = 0;
  for (let i = 0; i < bins.length; ++i) {
    if (cum + bins[i] >= target && bins[i] > 0) {
      const inside = (target - cum) / bins[i];
      return channel.lo + (i + Math.min(Math.max(inside, 0), 1)) * width;
    }
    cum += bins[i];
  }
  return channel.hi;
}

// The affine map file = offset + scale · stored of a channel (volume/value_map.h). The dataset
// JSON may carry it (`value_maps`); 8/16-bit types follow from dtype; wider types map their data
// range [lo, hi] onto the stored uint16 range, taken from the histogram's min/max.
export function valueMap(dataset, channelIndex, histogramChannel) {
  const given = dataset.value_maps?.[channelIndex];
  if (given && Number.isFinite(given.offset) && Number.isFinite(given.scale)) {
    return {offset: given.offset, scale: given.scale, storedMax: given.stored_max ?? storedMax(dataset.dtype)};
  }
  switch (dataset.dtype) {
    case 'uint8': return {offset: 0, scale: 1, storedMax: 255};
    case 'uint16': return {offset: 0, scale: 1, storedMax: 65535};
    case 'int8': return {offset: -128, scale: 1, storedMax: 255};
    case 'int16': return {offset: -32768, scale: 1, storedMax: 65535};
    default: {
      const lo = histogramChannel?.min ?? 0, hi = histogramChannel?.max ?? 65535;
      return {offset: lo, scale: hi > lo ? (hi - lo) / 65535 : 1, storedMax: 65535};
    }
  }
}

function storedMax(dtype) {
  return dtype === 'uint8' || dtype === 'int8' ? 255 : 65535;
}

export const toFile = (map, stored) => map.offset + map.scale * stored;
export const toStored = (map, file) => (file - map.offset) / map.scale;

// Window/level (stored units) from [low, high] (file units).
export function windowFromRange(map, low, high) {
  const a = toStored(map, low), b = toStored(map, high);
  const window = Math.max(b - a, 1e-6);
  return {window, level: a + window / 2};
}

// [low, high] in file units of a window/level in stored units.
export function rangeFromWindow(map, window, level) {
  return [toFile(map, level - window / 2), toFile(map, level + window / 2)];
}

// Auto-contrast: the window spanning the [qLow, qHigh] percentiles (default 0.1 %–99.9 %; the
// server's p001/p999 when asked for those), never empty.
export function autoContrast(channel, map, qLow = 0.001, qHigh = 0.999) {
  let low, high;
  if (qLow === 0.001 && qHigh === 0.999 && Number.isFinite(channel.p001) &&
      Number.isFinite(channel.p999) && channel.count !== 0) {
    low = channel.p001;
    high = channel.p999;
  } else {
    low = percentile(channel, qLow);
    high = percentile(channel, qHigh);
  }
  if (low === null || high === null) return null;
  if (!(high > low)) high = low + Math.max(map.scale, (channel.hi - channel.lo) / 256);
  return windowFromRange(map, low, high);
}

// Draws bins (log scale) and the window as a shaded ramp onto a canvas of its own size.
export function drawHistogram(canvas, channel, range, color, gamma = 1) {
  const ctx = canvas.getContext('2d');
  const w = canvas.width, h = canvas.height;
  ctx.clearRect(0, 0, w, h);
  ctx.fillStyle = '#16181d';
  ctx.fillRect(0, 0, w, h);
  if (!channel || !channel.bins?.length) return;
  const bins = channel.bins;
  const maxLog = Math.max(1, ...bins.map((b) => Math.log1p(b)));
  const rgb = color.map((c) => Math.round(c * 255)).join(',');
  ctx.fillStyle = `rgba(${rgb},0.75)`;
  for (let i = 0; i < bins.length; ++i) {
    const bh = Math.log1p(bins[i]) / maxLog * (h - 2);
    const x0 = i / bins.length * w, x1 = (i + 1) / bins.length * w;
    ctx.fillRect(x0, h - bh, Math.max(1, x1 - x0), bh);
  }
  // The window's transfer ramp, in the histogram's coordinates.
  const toX = (v) => (v - channel.lo) / (channel.hi - channel.lo) * w;
  const [a, b] = range;
  ctx.strokeStyle = '#fff';
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  for (let x = 0; x <= w; x += 2) {
    const v = channel.lo + x / w * (channel.hi - channel.lo);
    const t = Math.pow(Math.min(Math.max((v - a) / (b - a), 0), 1), gamma);
    const y = h - 1 - t * (h - 2);
    if (x === 0) ctx.moveTo(x, y); else ctx.lineTo(x, y);
  }
  ctx.stroke();
  ctx.fillStyle = 'rgba(255,255,255,0.9)';
  ctx.fillRect(toX(a) - 1, 0, 2, h);
  ctx.fillRect(toX(b) - 1, 0, 2, h);
}

// Formats a value in file units compactly (integers as such, floats to 4 significant digits).
export function formatValue(v) {
  if (!Number.isFinite(v)) return String(v);
  if (Math.abs(v - Math.round(v)) < 1e-9 && Math.abs(v) < 1e9) return String(Math.round(v));
  return Number(v.toPrecision(4)).toString();
}
