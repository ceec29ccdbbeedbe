// Participants: the client's model of who is in the live session (docs/protocol.md, "Sharing") —
// each participant's id, name, role (owner, controller, viewer), whether they are driving, and
// which one is this page — and what follows from it: whether this page may drive the view, whose
// view a viewer follows, which actions the owner has on each participant. Pure; the share panel
// and main.js render it. Names come from the server and are untrusted: callers show them as text.

export const ROLES = ['owner', 'controller', 'viewer'];
const ROLE_ORDER = {owner: 0, controller: 1, viewer: 2};
const MAX_NAME = 64;

export function canDrive(role) {
  return role === 'owner' || role === 'controller';
}

export function roleLabel(role) {
  return {owner: 'owner', controller: 'controller', viewer: 'viewer'}[role] ?? 'unknown';
}

// The name this page sends in `hello`: no control characters, spaces collapsed, at most
// MAX_NAME_BYTES of UTF-8 (the server counts bytes), never a code point cut in half; '' if none.
export const MAX_NAME_BYTES = 64;
export function cleanName(raw) {
  const s = String(raw ?? '').replace(/[\u0000-\u001f\u007f-\u009f]/g, ' ').replace(/\s+/g, ' ').trim();
  const encoder = new TextEncoder();
  let out = '';
  for (const ch of s) {
    if (encoder.encode(out + ch).length > MAX_NAME_BYTES) break;
    out += ch;
  }
  return out.trim();
}

// One participant of a `participants` event, checked and normalised; null when unusable.
export function normalizeParticipant(p) {
  if (!p || typeof p !== 'object') return null;
  const id = typeof p.id === 'number' || typeof p.id === 'string' ? String(p.id) : '';
  if (!id || !ROLES.includes(p.role)) return null;
  let name = typeof p.name === 'string' ? p.name.trim() : '';
  if (name.length > MAX_NAME) name = name.slice(0, MAX_NAME - 1) + '…';
  return {id, rawId: p.id, name: name || `participant ${id}`, role: p.role, driving: p.driving === true,
    you: p.you === true};
}

// Owner first, then controllers, then viewers; by name within a role (stable by id).
export function sortParticipants(list) {
  return list.slice().sort((a, b) => ROLE_ORDER[a.role] - ROLE_ORDER[b.role] ||
      a.name.localeCompare(b.name) || a.id.localeCompare(b.id));
}

export class Participants {
  constructor() {
    this.list = [];
    this.ownRole = null;  // From `welcome` until a `participants` event names this page.
  }

  // The list of a `participants` event (invalid entries dropped).
  update(list) {
    this.list = sortParticipants((Array.isArray(list) ? list : []).map(normalizeParticipant).filter(Boolean));
  }

  setOwnRole(role) {
    this.ownRole = ROLES.includes(role) ? role : null;
  }

  get me() {
    return this.list.find((p) => p.you) ?? null;
  }

  // This page's role: its entry in the list, else what `welcome` said.
  get role() {
    return this.me?.role ?? this.ownRole;
  }

  get canDrive() {
    return canDrive(this.role);
  }

  get owner() {
    return this.list.find((p) => p.role === 'owner') ?? null;
  }

  // The participant driving now (the latest state change, or one dragging); null when idle.
  get driver() {
    return this.list.find((p) => p.driving) ?? null;
  }

  // Whom a viewer follows: the one driving, else the owner.
  get followed() {
    return this.driver ?? this.owner;
  }

  // The banner a viewer sees; '' for those who may drive.
  bannerText() {
    if (this.canDrive || this.role === null) return '';
    const f = this.followed;
    return f && !f.you ? `Following ${f.name} — view only` : 'View only';
  }

  // The owner's actions on participant p: promote (viewer → controller), demote (controller →
  // viewer), kick. Nobody else has any, and nobody acts on the owner or on themselves.
  actionsFor(p) {
    if (this.role !== 'owner' || !p || p.you || p.role === 'owner') return [];
    return p.role === 'viewer' ? ['promote', 'kick'] : ['demote', 'kick'];
  }

  // The message for an action of actionsFor(p) (docs/protocol.md).
  actionMessage(action, p) {
    if (action === 'promote') return {type: 'participant_role', participant: p.rawId, role: 'controller'};
    if (action === 'demote') return {type: 'participant_role', participant: p.rawId, role: 'viewer'};
    if (action === 'kick') return {type: 'kick', participant: p.rawId};
    throw new Error(`unknown action ${action}`);
  }
}
