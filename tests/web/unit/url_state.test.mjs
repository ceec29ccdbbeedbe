import {test} from 'node:test';
import assert from 'node:assert/strict';
import {apiUrl, credentialParams, linkUrl, readUrlState, webSocketUrl, withDataset, withoutToken} from '../../../web/js/url_state.js';

const SHARE = 'q7Vt3kYxW0b9-Lm_2NcPzA';  // 22 base64url characters: 128 bits.
const VIEW = 'AAAAAAAAAAAAAAAAAAAAAA';

test('reads the dataset and token of a printed URL', () => {
  assert.deepEqual(readUrlState('http://127.0.0.1:8080/?token=abc-DEF_1.~&dataset=demo00000001'),
      {token: 'abc-DEF_1.~', dataset: 'demo00000001', share: '', view: '', mode: 'user'});
  assert.deepEqual(readUrlState('http://h/'), {token: '', dataset: '', share: '', view: '', mode: 'user'});
  assert.equal(readUrlState('http://h/?dataset=../etc').dataset, '');
  assert.equal(readUrlState('http://h/?dataset=ABC').dataset, '');
});

test('a share link joins, a view link opens a copy; malformed secrets are ignored', () => {
  const s = readUrlState(`https://lab.example/octo/?share=${SHARE}`);
  assert.equal(s.mode, 'share');
  assert.equal(s.share, SHARE);
  assert.deepEqual(credentialParams(s), {share: SHARE});
  const v = readUrlState(`https://lab.example/octo/?view=${VIEW}&token=t`);
  assert.equal(v.mode, 'view');
  assert.deepEqual(credentialParams(v), {view: VIEW});
  // A share link wins over a view link and a token; the token is never sent alongside it.
  const both = readUrlState(`http://h/?token=t&view=${VIEW}&share=${SHARE}&dataset=abc`);
  assert.equal(both.mode, 'share');
  assert.deepEqual(credentialParams(both), {share: SHARE});
  // Too short, or characters outside base64url: not a link.
  for (const bad of ['abc', `${SHARE.slice(0, 15)}`, `${SHARE}%2F`, `${SHARE}<`, 'x'.repeat(300)]) {
    const r = readUrlState(`http://h/?share=${bad}&token=t`);
    assert.equal(r.mode, 'user', bad);
    assert.equal(r.share, '');
    assert.deepEqual(credentialParams(r), {token: 't'});
  }
  assert.deepEqual(credentialParams(readUrlState('http://h/')), {});
});

test('withDataset keeps the token and replaces the dataset', () => {
  const u = withDataset('http://h:1/?token=t&dataset=a', 'b2');
  assert.deepEqual(readUrlState(u), {token: 't', dataset: 'b2', share: '', view: '', mode: 'user'});
  assert.equal(new URL(withDataset(u, '')).searchParams.has('dataset'), false);
});

test('WebSocket URL follows the page (scheme, host, sub-path) and carries one credential', () => {
  assert.equal(webSocketUrl('http://127.0.0.1:5/?token=x&dataset=d', 'x'), 'ws://127.0.0.1:5/ws?token=x');
  assert.equal(webSocketUrl('https://lab.example/octo/index.html?token=x', 'x'), 'wss://lab.example/octo/ws?token=x');
  assert.equal(webSocketUrl('http://h/', 'a b'), 'ws://h/ws?token=a+b');
  assert.equal(webSocketUrl(`https://lab.example/octoscope/?share=${SHARE}`, {share: SHARE}),
      `wss://lab.example/octoscope/ws?share=${SHARE}`);
  assert.equal(webSocketUrl(`http://h:9/a/b/?view=${VIEW}`, {view: VIEW}), `ws://h:9/a/b/ws?view=${VIEW}`);
  assert.equal(webSocketUrl('http://h/', {}), 'ws://h/ws');
});

test('API URLs are relative to the page', () => {
  assert.equal(apiUrl('https://lab.example/octo/?token=x', 'api/datasets'), 'https://lab.example/octo/api/datasets');
  assert.equal(apiUrl('http://h:2/', '/api/datasets/ab/histogram', 't'), 'http://h:2/api/datasets/ab/histogram?token=t');
  assert.equal(apiUrl(`https://lab.example/octo/?share=${SHARE}`, 'api/datasets', {share: SHARE}),
      `https://lab.example/octo/api/datasets?share=${SHARE}`);
});

test('a link made by the page holds only the link secret, under the page\'s prefix', () => {
  assert.equal(linkUrl('https://lab.example/octo/index.html?token=secret&dataset=a#x', 'share', SHARE),
      `https://lab.example/octo/?share=${SHARE}`);
  assert.equal(linkUrl('http://h:1/?token=t', 'view', VIEW), `http://h:1/?view=${VIEW}`);
});

test('the address bar loses the token, keeping everything else', () => {
  assert.equal(withoutToken('http://h:1/octo/?token=t&dataset=a1'), 'http://h:1/octo/?dataset=a1');
  assert.equal(withoutToken('http://h/?token=t'), 'http://h/');
  assert.equal(withoutToken(`http://h/?view=${VIEW}&token=t#x`), `http://h/?view=${VIEW}#x`);
  assert.equal(withoutToken('http://h/?dataset=a1'), 'http://h/?dataset=a1');
});
