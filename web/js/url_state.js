// URL state: what the page's address names — the credential it connects with (a user's
// `token=…`, a share link's `share=…`, a view link's `view=…`) and the dataset open
// (`?dataset=ID`), so a bookmark or a pasted link opens that dataset or joins that session
// directly. Every server URL is built relative to the page, so the client works behind a reverse
// proxy under a path prefix (https://host/octoscope/). Pure functions over URL strings; main.js
// applies them to window.location / history.

const ID_PATTERN = /^[a-z0-9_-]{1,64}$/;
// Share tokens and view ids are base64url (≥ 128 bits: 22 characters and up).
const SECRET_PATTERN = /^[A-Za-z0-9_-]{16,256}$/;

// {token, dataset, share, view, mode} from a URL (string). A dataset id, share token or view id
// that is not well-formed is ignored. `mode` says how the page connects: 'share' (joins a live
// session through a share link), 'view' (opens a view link as a new session of its own) or
// 'user' (a user token, or none: the server answers 401 and the page says so). A share link wins
// over a view link, which wins over a dataset.
export function readUrlState(href) {
  const url = new URL(href);
  const get = (k) => url.searchParams.get(k) || '';
  const token = get('token');
  const dataset = get('dataset');
  const share = SECRET_PATTERN.test(get('share')) ? get('share') : '';
  const view = SECRET_PATTERN.test(get('view')) ? get('view') : '';
  const mode = share ? 'share' : view ? 'view' : 'user';
  return {token, dataset: ID_PATTERN.test(dataset) ? dataset : '', share, view, mode};
}

// The query parameters that authenticate this page's requests (docs/api.md): one credential,
// the share link's or view link's own when the page was opened through one, else the token.
export function credentialParams(state) {
  if (state.mode === 'share') return {share: state.share};
  if (state.mode === 'view') return {view: state.view};
  return state.token ? {token: state.token} : {};
}

// The same URL naming `dataset` (removed when empty), other parameters kept.
export function withDataset(href, dataset) {
  const url = new URL(href);
  if (dataset) {
    url.searchParams.set('dataset', dataset);
  } else {
    url.searchParams.delete('dataset');
  }
  return url.toString();
}

// The same URL without the user token: what the address bar shows once the page has read it, so
// that a copied address never hands a colleague the token.
export function withoutToken(href) {
  const url = new URL(href);
  url.searchParams.delete('token');
  return url.toString();
}

// The folder of the page: every server URL is relative to it (path prefix behind a proxy).
function relativeToPage(href, path) {
  const url = new URL(href);
  const out = new URL(url.pathname.replace(/[^/]*$/, '') + path.replace(/^\//, ''), url);
  out.search = '';
  out.hash = '';
  return out;
}

// Accepts the old form (a token string) or credential params ({token} | {share} | {view}).
function applyCredentials(url, credentials) {
  const params = typeof credentials === 'string' ? (credentials ? {token: credentials} : {}) :
    (credentials ?? {});
  for (const [k, v] of Object.entries(params)) {
    if (v) url.searchParams.set(k, v);
  }
  return url;
}

// ws[s]://host/PREFIX/ws?CREDENTIAL for a page at `href` (http → ws, https → wss), the page's path
// prefix kept so the client works behind a reverse proxy under a sub-path.
export function webSocketUrl(href, credentials) {
  const ws = relativeToPage(href, 'ws');
  ws.protocol = new URL(href).protocol === 'https:' ? 'wss:' : 'ws:';
  return applyCredentials(ws, credentials).toString();
}

// An API URL relative to the page (`api/datasets`) with the credential in the query.
export function apiUrl(href, path, credentials) {
  return applyCredentials(relativeToPage(href, path), credentials).toString();
}

// A share or view link to this page when the server gave none: the page's own address with only
// `share=` or `view=` (never the user's token) in the query.
export function linkUrl(href, kind, secret) {
  const url = relativeToPage(href, '');
  url.searchParams.set(kind, secret);
  return url.toString();
}

export function isValidDatasetId(id) {
  return ID_PATTERN.test(id);
}
