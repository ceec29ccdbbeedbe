// URL state: what the page's address names — the dataset open (`?dataset=ID`) and the access
// token (`token=…`) — so a bookmark or a pasted link opens that dataset directly. Pure functions
// over URL strings; main.js applies them to window.location / history.

const ID_PATTERN = /^[a-z0-9_-]{1,64}$/;

// {token, dataset} from a URL (string). A dataset id that is not a valid id is ignored.
export function readUrlState(href) {
  const url = new URL(href);
  const token = url.searchParams.get('token') || '';
  const dataset = url.searchParams.get('dataset') || '';
  return {token, dataset: ID_PATTERN.test(dataset) ? dataset : ''};
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

// ws[s]://host/ws?token=… for a page at `href` (http → ws, https → wss), the page's path prefix
// kept so the client works behind a reverse proxy under a sub-path.
export function webSocketUrl(href, token) {
  const url = new URL(href);
  const ws = new URL(url.pathname.replace(/[^/]*$/, '') + 'ws', url);
  ws.protocol = url.protocol === 'https:' ? 'wss:' : 'ws:';
  ws.search = '';
  ws.hash = '';
  if (token) ws.searchParams.set('token', token);
  return ws.toString();
}

// An API URL relative to the page (`api/datasets`) with the token in the query.
export function apiUrl(href, path, token) {
  const url = new URL(href);
  const api = new URL(url.pathname.replace(/[^/]*$/, '') + path.replace(/^\//, ''), url);
  api.search = '';
  api.hash = '';
  if (token) api.searchParams.set('token', token);
  return api.toString();
}

export function isValidDatasetId(id) {
  return ID_PATTERN.test(id);
}
