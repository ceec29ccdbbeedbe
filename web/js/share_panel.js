// Share panel: the "Session" section of the side panel. Everyone sees the participants (role
// badges, who is driving, which one is "you") and can copy a view link (a snapshot of the view
// that opens as an independent session, optionally expiring). The owner also creates live share
// links (viewer or controller, optionally expiring), sees the active links and revokes them, and
// promotes, demotes or removes participants. A signed-in user also sees the view links they own
// (GET /api/views: which dataset, when made, expiry, whether it still opens) and deletes them.
// Session actions are messages through send(msg) (docs/protocol.md); the panel only renders what
// the server reports (`participants`, `shares`, `share_created`, `view_saved`, the API's list).

import {roleLabel} from './participants.js';

// One entry of a `shares` event, checked; null when unusable.
export function normalizeShare(s) {
  if (!s || typeof s !== 'object' || typeof s.token !== 'string' || !s.token) return null;
  if (s.role !== 'viewer' && s.role !== 'controller') return null;
  const expires = typeof s.expires === 'string' && s.expires ? s.expires :
    typeof s.expires === 'number' && s.expires > 0 ? s.expires : null;
  return {token: s.token, role: s.role, url: typeof s.url === 'string' ? s.url : '', expires,
    participants: Number.isInteger(s.participants) ? s.participants : null};
}

// "expires in 59 min", "expires in 3 h", "expires in 2 d", "expired", "no expiry". `expires` is an
// ISO-8601 time or seconds since the epoch.
export function describeExpiry(expires, nowMs = Date.now()) {
  if (expires === null || expires === undefined || expires === '') return 'no expiry';
  const t = typeof expires === 'number' ? expires * 1000 : Date.parse(expires);
  if (!Number.isFinite(t)) return 'no expiry';
  const s = (t - nowMs) / 1000;
  if (s <= 0) return 'expired';
  const minutes = Math.max(1, Math.round(s / 60));
  if (minutes < 60) return `expires in ${minutes} min`;
  const hours = Math.round(s / 3600);
  if (hours < 48) return `expires in ${hours} h`;
  return `expires in ${Math.round(s / 86400)} d`;
}

// One entry of GET /api/views, checked; null when unusable.
export function normalizeViewLink(v) {
  if (!v || typeof v !== 'object' || typeof v.id !== 'string' || !v.id) return null;
  const text = (x) => (typeof x === 'string' ? x : '');
  return {
    id: v.id, url: text(v.url), dataset: text(v.dataset), datasetName: text(v.dataset_name),
    madeThrough: text(v.made_through), owner: text(v.owner), created: text(v.created),
    expires: typeof v.expires === 'string' && v.expires ? v.expires : null,
    valid: v.valid === true, reason: text(v.reason),
  };
}

// How a view link is described in the list: "embryo.ome.tif · made 3 h ago · expires in 2 d",
// or why it no longer opens.
export function describeViewLink(v, nowMs = Date.now()) {
  const parts = [v.datasetName || v.dataset || 'unknown dataset'];
  const made = Date.parse(v.created);
  if (Number.isFinite(made)) parts.push(`made ${describeAge((nowMs - made) / 1000)}`);
  if (v.madeThrough === 'share') parts.push('by a guest');
  parts.push(v.valid ? describeExpiry(v.expires, nowMs) : `does not open: ${v.reason || 'no longer valid'}`);
  return parts.join(' · ');
}

function describeAge(seconds) {
  if (!(seconds >= 60)) return 'just now';
  const minutes = Math.round(seconds / 60);
  if (minutes < 60) return `${minutes} min ago`;
  const hours = Math.round(seconds / 3600);
  if (hours < 48) return `${hours} h ago`;
  return `${Math.round(seconds / 86400)} d ago`;
}

// A token shown in lists: its first characters only (the whole one is in the link).
export function abbreviateToken(token) {
  return token.length > 8 ? `${token.slice(0, 6)}…` : token;
}

// Copies text to the clipboard: the async clipboard API, else a selected field and the legacy
// copy command. Resolves true when the text was copied.
export async function copyText(text, field = null) {
  try {
    if (globalThis.navigator?.clipboard?.writeText) {
      await navigator.clipboard.writeText(text);
      return true;
    }
  } catch {
    // Not allowed here (no user gesture, insecure context): fall back below.
  }
  if (!field) return false;
  field.focus();
  field.select();
  try {
    return document.execCommand('copy');
  } catch {
    return false;
  }
}

const LINK_TITLES = {
  viewer: 'Viewer link — joins live, view only',
  controller: 'Controller link — joins live and may drive',
  view: 'View link — opens a copy of this view (not live)',
};

export class SharePanel {
  // handlers: send(msg) → bool (false when not connected), fallbackUrl(kind, secret) → string,
  // storedName() → the name this browser joins with, onName(name) stores a new one.
  constructor(root, handlers) {
    this.root = root;
    this.h = handlers;
    this.model = null;
    this.shares = [];
    this.viewLinks = [];
    const q = (s) => root.querySelector(s);
    this.el = {
      role: q('.my-role'), list: q('.participants'),
      owner: q('.share-owner'), links: q('.share-links'), result: q('.share-result'),
      resultTitle: q('.share-result .link-title'), url: q('.share-result input'),
      note: q('.share-result .note'), ttl: q('.share-ttl'), viewTtl: q('.view-ttl'),
      views: q('.view-links'), viewList: q('.view-link-list'),
    };
    q('.share-viewer').addEventListener('click', () => this.create('viewer'));
    q('.share-controller').addEventListener('click', () => this.create('controller'));
    q('.copy-view-link').addEventListener('click', () => {
      const msg = {type: 'view_save'};
      const ttl = Number(this.el.viewTtl?.value);
      if (Number.isFinite(ttl) && ttl > 0) msg.ttl_s = ttl;
      this.request(msg, 'view');
    });
    q('.refresh-view-links')?.addEventListener('click', () => this.refreshViewLinks());
    if (this.el.views) this.el.views.hidden = !handlers.listViews;
    this.refreshViewLinks();
    q('.share-result .copy').addEventListener('click', () => this.copy(this.el.url.value));
    this.el.url.addEventListener('focus', () => this.el.url.select());
    this.el.name = q('.name-input');
    this.el.name.value = handlers.storedName?.() ?? '';
    this.el.name.addEventListener('change', () => handlers.onName?.(this.el.name.value));
  }

  create(role) {
    const msg = {type: 'share_create', role};
    const ttl = Number(this.el.ttl?.value);
    if (Number.isFinite(ttl) && ttl > 0) msg.ttl_s = ttl;
    this.request(msg, role);
  }

  request(msg, kind) {
    if (!this.h.send(msg)) {
      this.showNote('Not connected — try again when the connection is back.');
      return;
    }
    this.waiting = kind;
    this.showNote(kind === 'view' ? 'Saving the view…' : 'Creating the link…');
  }

  showNote(text) {
    this.el.result.hidden = false;
    this.el.note.textContent = text;
  }

  // A link the server made (`share_created` or `view_saved`): shown in the field and copied.
  async showLink(kind, url) {
    this.waiting = null;
    this.el.result.hidden = false;
    this.el.result.dataset.kind = kind;
    this.el.resultTitle.textContent = LINK_TITLES[kind] ?? 'Link';
    this.el.url.value = url;
    await this.copy(url);
  }

  async copy(url) {
    if (!url) return;
    const ok = await copyText(url, this.el.url);
    this.el.note.textContent = ok ? 'Copied to the clipboard.' : 'Copy the link from the field above.';
    this.el.result.dataset.copied = ok ? 'yes' : 'no';
  }

  // The participants (a Participants model) changed: the list, this page's role, owner tools.
  setParticipants(model) {
    this.model = model;
    const role = model.role;
    this.el.role.textContent = role ? roleLabel(role) : '';
    this.el.role.className = `my-role role-badge role-${role ?? 'none'}`;
    this.el.role.hidden = !role;
    this.el.owner.hidden = role !== 'owner';
    this.el.name.placeholder = model.me?.name ?? 'shown to the others';
    this.el.list.replaceChildren(...model.list.map((p) => this.participantItem(p)));
    this.root.dataset.role = role ?? '';
  }

  participantItem(p) {
    const li = document.createElement('li');
    li.className = 'participant';
    li.dataset.id = p.id;
    li.dataset.role = p.role;
    if (p.you) li.classList.add('you');
    if (p.driving) li.classList.add('driving');
    const name = document.createElement('span');
    name.className = 'name';
    name.textContent = p.name;
    name.title = p.name;
    li.appendChild(name);
    if (p.you) {
      const you = document.createElement('span');
      you.className = 'you-tag';
      you.textContent = '(you)';
      li.appendChild(you);
    }
    const badge = document.createElement('span');
    badge.className = `role-badge role-${p.role}`;
    badge.textContent = roleLabel(p.role);
    li.appendChild(badge);
    const drive = document.createElement('span');
    drive.className = 'driving-marker';
    drive.textContent = p.driving ? '● driving' : '';
    drive.hidden = !p.driving;
    li.appendChild(drive);
    li.setAttribute('aria-label', `${p.name}${p.you ? ' (you)' : ''}, ${roleLabel(p.role)}${p.driving ? ', driving' : ''}`);
    const labels = {
      promote: ['Make controller', `Let ${p.name} drive the view (controller)`],
      demote: ['Make viewer', `Make ${p.name} a viewer (view only)`],
      kick: ['Remove', `Remove ${p.name} from the session`],
    };
    const actions = document.createElement('span');
    actions.className = 'actions';
    for (const action of this.model.actionsFor(p)) {
      const b = document.createElement('button');
      b.className = `action ${action}`;
      b.dataset.action = action;
      b.textContent = labels[action][0];
      b.title = labels[action][1];
      b.setAttribute('aria-label', labels[action][1]);
      b.addEventListener('click', () => this.h.send(this.model.actionMessage(action, p)));
      actions.appendChild(b);
    }
    if (actions.childElementCount) li.appendChild(actions);
    return li;
  }

  // The view links this user owns, from the server (GET api/views).
  async refreshViewLinks() {
    if (!this.h.listViews) return;
    try {
      const list = await this.h.listViews();
      this.viewLinks = (Array.isArray(list) ? list : []).map(normalizeViewLink).filter(Boolean);
    } catch {
      return;  // Not reachable now: the list stays as it was.
    }
    this.renderViewLinks();
  }

  renderViewLinks() {
    if (!this.el.viewList) return;
    const items = this.viewLinks.map((v) => {
      const li = document.createElement('li');
      li.className = 'view-link';
      li.dataset.id = v.id;
      li.dataset.valid = v.valid ? 'yes' : 'no';
      const info = document.createElement('span');
      info.className = 'info';
      info.textContent = describeViewLink(v);
      info.title = info.textContent;
      const copy = document.createElement('button');
      copy.className = 'copy';
      copy.textContent = 'Copy';
      copy.disabled = !v.valid || !v.url;
      copy.setAttribute('aria-label', `Copy the view link of ${v.datasetName || v.dataset}`);
      copy.addEventListener('click', () => this.showLink('view', v.url));
      const del = document.createElement('button');
      del.className = 'delete';
      del.textContent = 'Delete';
      del.title = 'The link stops working for everyone who has it';
      del.setAttribute('aria-label', `Delete the view link of ${v.datasetName || v.dataset}`);
      del.addEventListener('click', async () => {
        del.disabled = true;
        const ok = await this.h.deleteView?.(v.id).catch(() => false);
        if (!ok) this.showNote('The view link could not be deleted; try again.');
        await this.refreshViewLinks();
      });
      li.append(info, copy, del);
      return li;
    });
    this.el.viewList.replaceChildren(...items);
    this.el.viewList.dataset.count = String(items.length);
  }

  // The active share links (`shares`, owner only).
  setShares(list) {
    this.shares = (Array.isArray(list) ? list : []).map(normalizeShare).filter(Boolean);
    this.renderShares();
  }

  renderShares() {
    const items = this.shares.map((s) => {
      const li = document.createElement('li');
      li.className = 'share-link';
      li.dataset.token = s.token;
      li.dataset.role = s.role;
      const badge = document.createElement('span');
      badge.className = `role-badge role-${s.role}`;
      badge.textContent = roleLabel(s.role);
      const tok = document.createElement('code');
      tok.textContent = abbreviateToken(s.token);
      tok.title = 'The start of the link\'s token';
      const info = document.createElement('span');
      info.className = 'info';
      info.textContent = describeExpiry(s.expires) +
          (s.participants !== null ? ` · ${s.participants} joined` : '');
      const url = s.url || this.h.fallbackUrl('share', s.token);
      const copy = document.createElement('button');
      copy.className = 'copy';
      copy.textContent = 'Copy';
      copy.setAttribute('aria-label', `Copy the ${s.role} link ${abbreviateToken(s.token)}`);
      copy.addEventListener('click', () => this.showLink(s.role, url));
      const revoke = document.createElement('button');
      revoke.className = 'revoke';
      revoke.textContent = 'Revoke';
      revoke.setAttribute('aria-label', `Revoke the ${s.role} link ${abbreviateToken(s.token)}: ` +
          'it stops working and those who joined through it leave');
      revoke.title = 'The link stops working; those who joined through it are disconnected';
      revoke.addEventListener('click', () => this.h.send({type: 'share_revoke', token: s.token}));
      li.append(badge, tok, info, copy, revoke);
      return li;
    });
    this.el.links.replaceChildren(...items);
    this.el.links.dataset.count = String(items.length);
  }
}
