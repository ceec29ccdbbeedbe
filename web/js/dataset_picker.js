// Dataset picker: the server's datasets (GET /api/datasets) with size, channels, type, spacing
// and state (a building or streaming dataset shows its progress, refreshed every 2 s while the
// picker is open); choosing one calls onPick(id).

export function describeSize(d) {
  const [x, y, z] = d.size;
  const bytes = x * y * z * d.channels * (d.dtype.endsWith('8') ? 1 : d.dtype.endsWith('16') ? 2 :
      d.dtype.endsWith('64') ? 8 : 4);
  return `${x} × ${y} × ${z} · ${formatBytes(bytes)}`;
}

export function formatBytes(n) {
  const units = ['B', 'KB', 'MB', 'GB', 'TB'];
  let i = 0;
  while (n >= 1000 && i < units.length - 1) {
    n /= 1000;
    ++i;
  }
  return `${n >= 100 || i === 0 ? Math.round(n) : n.toPrecision(3)} ${units[i]}`;
}

export function describeState(d) {
  if (d.state === 'error') return `error: ${d.error ?? 'unknown'}`;
  if (d.state === 'building' || d.state === 'streaming') {
    return `${d.state} ${Math.floor((d.progress ?? 0) * 100)} % (${d.planes_inserted}/${d.planes_total} planes)`;
  }
  if (d.state === 'ready' && d.missing_planes) return `ready, ${d.missing_planes} planes missing`;
  return d.state;
}

export class DatasetPicker {
  constructor(dialog, fetchList, onPick) {
    this.dialog = dialog;
    this.fetchList = fetchList;
    this.onPick = onPick;
    this.timer = null;
    this.body = dialog.querySelector('tbody');
    this.message = dialog.querySelector('.message');
    dialog.querySelector('.close').addEventListener('click', () => this.close());
    dialog.addEventListener('close', () => clearInterval(this.timer));
  }

  async open() {
    if (!this.dialog.open) this.dialog.showModal();
    await this.refresh();
    clearInterval(this.timer);
    this.timer = setInterval(() => this.refresh(), 2000);
  }

  close() {
    clearInterval(this.timer);
    if (this.dialog.open) this.dialog.close();
  }

  async refresh() {
    let list;
    try {
      list = await this.fetchList();
    } catch (e) {
      this.message.textContent = `Cannot list datasets: ${e.message}`;
      return;
    }
    this.message.textContent = list.length ? '' :
        'The server has no datasets. Start it with --data DIR, --demo or --watch DIR.';
    this.body.replaceChildren(...list.map((d) => {
      const tr = document.createElement('tr');
      tr.dataset.id = d.id;
      tr.className = `state-${d.state}`;
      const cells = [
        d.name,
        describeSize(d),
        `${d.channels}${d.channel_names?.some(Boolean) ? ' (' + d.channel_names.join(', ') + ')' : ''}`,
        d.dtype,
        `${d.spacing.map((s) => Number(s.toPrecision(4))).join(' × ')} µm`,
        describeState(d),
      ];
      for (const c of cells) {
        const td = document.createElement('td');
        td.textContent = c;
        tr.appendChild(td);
      }
      const td = document.createElement('td');
      const b = document.createElement('button');
      b.textContent = 'Open';
      b.disabled = d.state === 'error';
      b.addEventListener('click', () => {
        this.close();
        this.onPick(d.id);
      });
      td.appendChild(b);
      tr.appendChild(td);
      tr.addEventListener('dblclick', () => b.click());
      return tr;
    }));
  }
}
