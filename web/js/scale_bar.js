// Scale bar: a "nice" length (1, 2 or 5 × 10^k µm, shown in nm/µm/mm) whose bar is at most
// `maxPx` pixels long at `umPerPx`, and its drawing onto a 2-D canvas context. Pure except draw.

export function niceScaleBar(umPerPx, maxPx) {
  if (!(umPerPx > 0) || !(maxPx > 0) || !Number.isFinite(umPerPx)) return null;
  const maxUm = umPerPx * maxPx;
  let best = null;
  for (let k = Math.floor(Math.log10(maxUm)) - 1; k <= Math.floor(Math.log10(maxUm)); ++k) {
    for (const m of [1, 2, 5]) {
      const um = m * Math.pow(10, k);
      if (um <= maxUm * (1 + 1e-9) && (!best || um > best.um)) best = {um};
    }
  }
  if (!best) return null;
  best.px = best.um / umPerPx;
  best.label = formatLength(best.um);
  return best;
}

export function formatLength(um) {
  const fmt = (x) => String(Number(x.toPrecision(6)));
  if (um >= 1000) return `${fmt(um / 1000)} mm`;
  if (um < 1) return `${fmt(um * 1000)} nm`;
  return `${fmt(um)} µm`;
}

// Draws the bar at the bottom-right corner of a canvas context (in its own pixel units).
export function drawScaleBar(ctx, umPerPx, width, height, scale = 1) {
  const bar = niceScaleBar(umPerPx, Math.min(200 * scale, width * 0.3));
  if (!bar) return;
  const margin = 14 * scale, thick = 4 * scale;
  const x1 = width - margin, x0 = x1 - bar.px, y = height - margin;
  ctx.save();
  ctx.font = `${12 * scale}px system-ui, sans-serif`;
  ctx.textAlign = 'center';
  ctx.textBaseline = 'bottom';
  ctx.fillStyle = 'rgba(0,0,0,0.55)';
  ctx.fillRect(x0 - 1 * scale, y - thick - 1 * scale, bar.px + 2 * scale, thick + 2 * scale);
  ctx.fillStyle = '#fff';
  ctx.fillRect(x0, y - thick, bar.px, thick);
  ctx.shadowColor = 'rgba(0,0,0,0.9)';
  ctx.shadowBlur = 3 * scale;
  ctx.fillText(bar.label, (x0 + x1) / 2, y - thick - 3 * scale);
  ctx.restore();
}
