// The farm's HTTP API as the page calls it: JSON in and out, errors as ApiError (the status and
// the API's own words), and the token: `/#token=SECRET` (kept in sessionStorage, removed from the
// address bar), or asked for by one prompt when the API answers 401.

import { sleep } from './dom.js';

const TOKEN_KEY = 'enip-farm-token';

let token = sessionStorage.getItem(TOKEN_KEY);
const fromHash = /(?:^#|&)token=([^&]*)/.exec(location.hash);
if (fromHash) {
  token = decodeURIComponent(fromHash[1]);
  sessionStorage.setItem(TOKEN_KEY, token);
  history.replaceState(null, '', location.pathname + location.search);
}
let asking = null;

function askToken() {  // one prompt for every request that got 401 meanwhile
  if (!asking) {
    asking = sleep(0).then(() => {
      const given = prompt('This farm\'s HTTP API needs its token (serve --token):', '');
      asking = null;
      if (!given) return false;
      token = given.trim();
      sessionStorage.setItem(TOKEN_KEY, token);
      return true;
    });
  }
  return asking;
}

export class ApiError extends Error {
  constructor(status, detail) { super(detail); this.status = status; }
}

// A FastAPI error's detail in one line: its text, or each item's field and message.
export function errorText(answer, fallback) {
  if (typeof answer.detail === 'string') return answer.detail;
  const items = (answer.detail || []).map(item => `${(item.loc || []).slice(1).join('.')}: ${item.msg}`);
  return items.length ? items.join('; ') : fallback;
}

// options: method, json (the body), stream (the Response, not its JSON), answers (statuses whose
// body is the answer), timeoutMs (a request the browser holds, e.g. across a network change, fails).
export async function api(path, options = {}) {
  for (let attempt = 0; ; attempt++) {
    const used = token;
    const headers = {};
    if (used) headers.Authorization = 'Bearer ' + used;
    let body;
    if (options.json !== undefined) {
      headers['Content-Type'] = 'application/json';
      body = JSON.stringify(options.json);
    }
    const signal = options.timeoutMs ? AbortSignal.timeout(options.timeoutMs) : undefined;
    const response = await fetch(path, { method: options.method || 'GET', headers, body, cache: 'no-store', signal });
    if (response.status === 401 && attempt < 3 && (token !== used || await askToken())) continue;
    if (!response.ok && !(options.answers || []).includes(response.status)) {
      let detail = response.statusText;
      try {
        detail = errorText(await response.json(), detail);
      } catch (error) { /* not JSON */ }
      throw new ApiError(response.status, `${response.status} ${detail}`);
    }
    return options.stream ? response : response.json();
  }
}

export const devicePath = name => 'devices/' + encodeURIComponent(name);
