// The sharing modules of the client: the participants model (roles, who drives, whom a viewer
// follows, the owner's actions), the share links list and the close codes a participant sees.
import {test} from 'node:test';
import assert from 'node:assert/strict';
import {canDrive, cleanName, MAX_NAME_BYTES, normalizeParticipant, Participants, sortParticipants} from '../../../web/js/participants.js';
import {abbreviateToken, describeExpiry, describeViewLink, normalizeShare, normalizeViewLink} from '../../../web/js/share_panel.js';
import {closeOutcome, CLOSE_ACCESS_ENDED, CLOSE_GONE, CLOSE_KICKED, CLOSE_RESUMED_ELSEWHERE, CLOSE_REVOKED} from '../../../web/js/connection.js';

const event = [
  {id: 3, name: 'carol', role: 'viewer', driving: false, you: true},
  {id: 1, name: 'alice', role: 'owner', driving: false, you: false},
  {id: 2, name: 'bob', role: 'controller', driving: true, you: false},
  {id: 4, name: 'ann', role: 'viewer', driving: false, you: false},
];

test('roles: owners and controllers drive, viewers do not', () => {
  assert.equal(canDrive('owner'), true);
  assert.equal(canDrive('controller'), true);
  assert.equal(canDrive('viewer'), false);
  assert.equal(canDrive(null), false);
  assert.equal(canDrive('admin'), false);
});

test('participants: sorted owner, controllers, viewers; hostile entries dropped', () => {
  const m = new Participants();
  m.update([...event, null, 7, {id: 9, name: 'x', role: 'god'}, {name: 'no id', role: 'viewer'},
    {id: 5, name: 'y'.repeat(500), role: 'viewer'}, {id: 6, name: '   ', role: 'viewer'}]);
  assert.deepEqual(m.list.map((p) => p.id), ['1', '2', '4', '3', '6', '5']);
  assert.equal(m.list.find((p) => p.id === '5').name.length, 64);
  assert.equal(m.list.find((p) => p.id === '6').name, 'participant 6');
  assert.equal(normalizeParticipant({id: {}, role: 'viewer'}), null);
  m.update('not a list');
  assert.deepEqual(m.list, []);
  assert.deepEqual(sortParticipants([]), []);
});

test('a viewer follows whoever drives, else the owner', () => {
  const m = new Participants();
  m.setOwnRole('viewer');  // welcome, before the first participants event
  assert.equal(m.canDrive, false);
  assert.equal(m.bannerText(), 'View only');
  m.update(event);
  assert.equal(m.role, 'viewer');
  assert.equal(m.me.name, 'carol');
  assert.equal(m.driver.name, 'bob');
  assert.equal(m.bannerText(), 'Following bob — view only');
  m.update(event.map((p) => ({...p, driving: false})));
  assert.equal(m.driver, null);
  assert.equal(m.bannerText(), 'Following alice — view only');
  // Promoted: the list names this page a controller; no banner.
  m.update(event.map((p) => (p.you ? {...p, role: 'controller'} : p)));
  assert.equal(m.role, 'controller');
  assert.equal(m.canDrive, true);
  assert.equal(m.bannerText(), '');
});

test('only the owner acts on others, never on the owner or itself', () => {
  const viewer = new Participants();
  viewer.update(event);
  for (const p of viewer.list) assert.deepEqual(viewer.actionsFor(p), []);
  const owner = new Participants();
  owner.update(event.map((p) => ({...p, you: p.role === 'owner'})));
  const by = (name) => owner.list.find((p) => p.name === name);
  assert.deepEqual(owner.actionsFor(by('alice')), []);
  assert.deepEqual(owner.actionsFor(by('bob')), ['demote', 'kick']);
  assert.deepEqual(owner.actionsFor(by('carol')), ['promote', 'kick']);
  // The messages carry the server's id unchanged (a number stays a number).
  assert.deepEqual(owner.actionMessage('promote', by('carol')), {type: 'participant_role', participant: 3, role: 'controller'});
  assert.deepEqual(owner.actionMessage('demote', by('bob')), {type: 'participant_role', participant: 2, role: 'viewer'});
  assert.deepEqual(owner.actionMessage('kick', by('ann')), {type: 'kick', participant: 4});
  assert.throws(() => owner.actionMessage('ban', by('ann')));
});

test('share links: checked, expiry described, tokens abbreviated', () => {
  assert.equal(normalizeShare({token: 'abc', role: 'owner'}), null);
  assert.equal(normalizeShare({role: 'viewer'}), null);
  assert.deepEqual(normalizeShare({token: 'tok', role: 'viewer', url: 'https://h/?share=tok', expires: null}),
      {token: 'tok', role: 'viewer', url: 'https://h/?share=tok', expires: null, participants: null});
  const now = Date.parse('2026-11-25T10:00:00Z');
  assert.equal(describeExpiry(null, now), 'no expiry');
  assert.equal(describeExpiry('', now), 'no expiry');
  assert.equal(describeExpiry('2026-11-25T10:30:00Z', now), 'expires in 30 min');
  assert.equal(describeExpiry('2026-11-25T10:00:10Z', now), 'expires in 1 min');
  assert.equal(describeExpiry('2026-11-25T10:59:55Z', now), 'expires in 1 h');  // not "60 min"
  assert.equal(describeExpiry('2026-11-25T10:59:00Z', now), 'expires in 59 min');
  assert.equal(describeExpiry('2026-11-25T13:00:00Z', now), 'expires in 3 h');
  assert.equal(describeExpiry('2026-12-02T10:00:00Z', now), 'expires in 7 d');
  assert.equal(describeExpiry('2026-11-25T09:00:00Z', now), 'expired');
  assert.equal(describeExpiry(now / 1000 + 7200, now), 'expires in 2 h');
  assert.equal(describeExpiry('garbage', now), 'no expiry');
  assert.equal(abbreviateToken('q7Vt3kYxW0b9-Lm_2NcPzA'), 'q7Vt3k…');
  assert.equal(abbreviateToken('short'), 'short');
});

test('close codes: revoked and removed participants do not come back; busy servers are retried', () => {
  assert.deepEqual(closeOutcome(CLOSE_REVOKED, 'share link revoked'),
      {retry: false, message: 'The owner revoked this share link — you have left the session.'});
  assert.match(closeOutcome(CLOSE_REVOKED, 'share link revoked', false).message, /no longer works/);
  assert.equal(closeOutcome(CLOSE_KICKED, '').retry, false);
  assert.match(closeOutcome(CLOSE_KICKED, 'removed from the session').message, /removed you/);
  assert.equal(CLOSE_REVOKED, 4001);  // docs/protocol.md
  assert.equal(CLOSE_RESUMED_ELSEWHERE, 4002);
  assert.equal(CLOSE_KICKED, 4003);
  assert.equal(CLOSE_GONE, 4004);
  assert.equal(closeOutcome(CLOSE_RESUMED_ELSEWHERE, 'resumed elsewhere').retry, false);
  assert.match(closeOutcome(CLOSE_GONE, 'view abc does not exist').message, /no longer exists \(view abc does not exist\)/);
  assert.equal(closeOutcome(1008, 'too many malformed messages').retry, false);
  assert.equal(closeOutcome(1009, '').message, 'The server closed the connection: 1009');
  assert.deepEqual(closeOutcome(1013, 'session full'), {retry: true, message: 'server busy: session full'});
  assert.equal(closeOutcome(1006, '').retry, true);
  assert.equal(closeOutcome(1001, 'server shutting down').retry, true);
});

test('the name sent in hello: clean, at most 64 bytes of UTF-8, never half a character', () => {
  assert.equal(cleanName('  Ada\tLovelace\n '), 'Ada Lovelace');
  assert.equal(cleanName('\u0000\u0007'), '');
  assert.equal(cleanName(null), '');
  assert.equal(cleanName('a'.repeat(100)), 'a'.repeat(64));
  const cut = cleanName('é'.repeat(40));  // 2 bytes each: 32 fit
  assert.equal(cut, 'é'.repeat(32));
  const emoji = cleanName('x' + '🔬'.repeat(20));  // 4 bytes each: 15 fit after the x
  assert.equal(new TextEncoder().encode(emoji).length, 61);
  assert.ok(new TextEncoder().encode(cleanName('日本語'.repeat(30))).length <= MAX_NAME_BYTES);
});

test('view links: entries of GET api/views checked; described by dataset, age, expiry or why not', () => {
  assert.equal(normalizeViewLink(null), null);
  assert.equal(normalizeViewLink({id: ''}), null);
  assert.equal(normalizeViewLink({id: 7}), null);
  const now = Date.parse('2026-11-28T12:00:00Z');
  const v = normalizeViewLink({id: 'AAAAAAAAAAAAAAAAAAAAAA', url: 'https://h/?view=A', dataset: 'a1',
    dataset_name: 'embryo.ome.tif', made_through: 'user', owner: 'alice',
    created: '2026-11-28T09:00:00Z', expires: '2026-11-30T12:00:00Z', valid: true, reason: null});
  assert.equal(v.datasetName, 'embryo.ome.tif');
  assert.equal(v.reason, '');
  assert.equal(describeViewLink(v, now), 'embryo.ome.tif · made 3 h ago · expires in 2 d');
  const guest = normalizeViewLink({id: 'B', dataset: 'a1', made_through: 'share', created: '2026-11-28T11:59:30Z',
    expires: null, valid: false, reason: 'the share link was revoked or expired'});
  assert.equal(describeViewLink(guest, now),
      'a1 · made just now · by a guest · does not open: the share link was revoked or expired');
  // Hostile fields become harmless text.
  const odd = normalizeViewLink({id: 'C', url: {x: 1}, dataset_name: 5, valid: 'yes', created: 'soon'});
  assert.equal(odd.url, '');
  assert.equal(odd.valid, false);
  assert.equal(describeViewLink(odd, now), 'unknown dataset · does not open: no longer valid');
});

test('an ended grant (4005) and an expired link (4001) say so and do not retry', () => {
  const ended = closeOutcome(CLOSE_ACCESS_ENDED, 'access ended: token expired');
  assert.equal(ended.retry, false);
  assert.equal(ended.message, 'Your access to this session ended (token expired).');
  assert.equal(closeOutcome(CLOSE_ACCESS_ENDED, '').message, 'Your access to this session ended.');
  const expired = closeOutcome(CLOSE_REVOKED, 'share link expired');
  assert.equal(expired.retry, false);
  assert.match(expired.message, /expired/);
});
