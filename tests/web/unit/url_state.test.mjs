import {test} from 'node:test';
import assert from 'node:assert/strict';
import {apiUrl, readUrlState, webSocketUrl, withDataset} from '../../../web/js/url_state.js';

test('reads the dataset and token of a printed URL', () => {
  assert.deepEqual(readUrlState('http://127.0.0.1:8080/?token=abc-DEF_1.~&dataset=demo00000001'),
      {token: 'abc-DEF_1.~', dataset: 'demo00000001'});
  assert.deepEqual(readUrlState('http://h/'), {token: '', dataset: ''});
  assert.equal(readUrlState('http://h/?dataset=../etc').dataset, '');
  assert.equal(readUrlState('http://h/?dataset=ABC').dataset, '');
});

test('withDataset keeps the token and replaces the dataset', () => {
  const u = withDataset('http://h:1/?token=t&dataset=a', 'b2');
  assert.deepEqual(readUrlState(u), {token: 't', dataset: 'b2'});
  assert.equal(new URL(withDataset(u, '')).searchParams.has('dataset'), false);
});

test('WebSocket URL follows the page (scheme, host, sub-path)', () => {
  assert.equal(webSocketUrl('http://127.0.0.1:5/?token=x&dataset=d', 'x'), 'ws://127.0.0.1:5/ws?token=x');
  assert.equal(webSocketUrl('https://lab.example/octo/index.html?token=x', 'x'), 'wss://lab.example/octo/ws?token=x');
  assert.equal(webSocketUrl('http://h/', 'a b'), 'ws://h/ws?token=a+b');
});

test('API URLs are relative to the page', () => {
  assert.equal(apiUrl('https://lab.example/octo/?token=x', 'api/datasets'), 'https://lab.example/octo/api/datasets');
  assert.equal(apiUrl('http://h:2/', '/api/datasets/ab/histogram', 't'), 'http://h:2/api/datasets/ab/histogram?token=t');
});
