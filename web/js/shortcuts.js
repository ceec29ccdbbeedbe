// Keyboard shortcuts: one table that both dispatches keys and fills the help overlay ("?"), so
// the overlay never lists a key that does nothing. Keys typed into form fields are left alone.
// Entries marked `drives` change the shared view: a viewer of a shared session cannot use them.

export const SHORTCUTS = [
  {keys: ['?', 'h'], label: 'Show / hide this help', action: 'help'},
  {keys: ['o'], label: 'Open a dataset (picker)', action: 'picker', drives: true},
  {keys: ['r'], label: 'Reset the view (iso, whole volume)', action: 'reset', drives: true},
  {keys: ['i'], label: 'Iso view', action: 'preset:iso', drives: true},
  {keys: ['x', 'X'], label: 'View along +x / −x (shift)', action: 'preset:x', drives: true},
  {keys: ['y', 'Y'], label: 'View along +y / −y (shift)', action: 'preset:y', drives: true},
  {keys: ['z', 'Z'], label: 'View along +z / −z (shift)', action: 'preset:z', drives: true},
  {keys: ['m'], label: 'Cycle DVR → MIP → MinIP', action: 'mode', drives: true},
  {keys: ['p'], label: 'Orthographic / perspective', action: 'projection', drives: true},
  {keys: ['a'], label: 'Auto-contrast every channel', action: 'auto', drives: true},
  {keys: ['1', '2', '3', '4', '5', '6', '7', '8', '9'], label: 'Show / hide channel n', action: 'channel', drives: true},
  {keys: ['f'], label: 'Enlarge / restore the view under the pointer', action: 'enlarge'},
  {keys: ['Escape'], label: 'Restore the layout, close dialogs', action: 'escape'},
  {keys: ['ArrowLeft', 'ArrowRight', 'ArrowUp', 'ArrowDown'], label: 'Orbit the 3-D view by 5°', action: 'orbit', drives: true},
  {keys: ['+', '-'], label: 'Zoom the 3-D view in / out', action: 'zoom', drives: true},
  {keys: ['PageUp', 'PageDown'], label: 'Move the slice under the pointer (shift: 10 voxels)', action: 'slice', drives: true},
  {keys: ['s'], label: 'Screenshot', action: 'screenshot'},
  {keys: ['.'], label: 'Show / hide the stats overlay', action: 'stats'},
];

export const MOUSE_HELP = [
  ['3-D view: left drag', 'orbit'],
  ['right / middle / shift drag', 'pan'],
  ['ctrl drag', 'roll'],
  ['wheel · pinch', 'zoom'],
  ['slice: click / drag', 'move the other two planes there'],
  ['slice: wheel', 'move this plane (shift: 10 voxels)'],
  ['slice: right / shift drag', 'move this plane continuously'],
];

const KEY_NAMES = {ArrowLeft: '←', ArrowRight: '→', ArrowUp: '↑', ArrowDown: '↓', Escape: 'Esc',
  PageUp: 'PgUp', PageDown: 'PgDn'};

// Whether an action changes the shared view (camera, parameters, slices, dataset).
export function drivesView(action) {
  return SHORTCUTS.some((s) => s.action === action && s.drives === true);
}

// The action for a keyboard event, or null.
export function actionFor(event) {
  const t = event.target;
  if (t && event.key !== 'Escape') {
    // Text fields take every key; sliders and checkboxes keep arrows and paging to themselves.
    const type = t.tagName === 'INPUT' ? (t.type || 'text') : '';
    if (t.tagName === 'SELECT' || t.tagName === 'TEXTAREA' || t.isContentEditable) return null;
    if (t.tagName === 'INPUT' && !['range', 'checkbox', 'radio', 'button', 'color'].includes(type)) return null;
    if (t.tagName === 'INPUT' && /^(Arrow|Page)/.test(event.key)) return null;
  }
  if (event.ctrlKey || event.metaKey || event.altKey) return null;
  const entry = SHORTCUTS.find((s) => s.keys.includes(event.key));
  return entry ? entry.action : null;
}

export function fillHelp(table) {
  const rows = SHORTCUTS.map((s) => [s.keys.map((k) => KEY_NAMES[k] ?? k).join(' '), s.label])
      .concat(MOUSE_HELP);
  table.replaceChildren(...rows.map(([k, label]) => {
    const tr = document.createElement('tr');
    const th = document.createElement('th');
    th.textContent = k;
    const td = document.createElement('td');
    td.textContent = label;
    tr.append(th, td);
    return tr;
  }));
}
