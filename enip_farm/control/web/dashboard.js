// enip-farm dashboard: every device of the farm as a card, driven through the HTTP API.
//
// Data: GET devices (the list, once), GET state?device=... (signals with values, connections,
// counters, faults) for the cards on screen, when they appear and every POLL_MS, and the event
// stream GET events (fetch, so that it can carry the token), whose "io" events update the signals
// between polls. A snapshot carries the server's monotonic time, read before the images: a signal
// changed by an event at or after that time keeps the event's value.
// Rendering: cards have a fixed size and only those on screen (and a row either side) exist in the
// DOM; all DOM work happens in one requestAnimationFrame callback, whatever the event rate.
// Token: `/#token=SECRET` (kept in sessionStorage, removed from the address bar), or asked for by
// a prompt when the API answers 401.
// The plant's overview (overview.js) uses what `window.enipFarm` gives it: the API, the message
// line, the stream's events, the events panel's history and the card of one device.
'use strict';
(() => {
  const CARD_W = 360, CARD_H = 380, GAP = 10, BUFFER_ROWS = 1;
  const POLL_MS = 1000, STATE_BATCH = 40, LOG_MAX = 300, LOG_PER_FRAME = 20, RETRY_MS = 1000;
  const FAULT_KINDS = ['delay', 'drop', 'close', 'reset', 'offline', 'status', 'stop-io', 'identity'];
  const PARAM_HINT = { delay: 'ms', status: 'svc status' };
  const REFRESH_KINDS = new Set(['connection opened', 'connection closed', 'connection timed out',
    'fault injected', 'fault cleared', 'session registered', 'session ended', 'tcp connected', 'tcp closed']);
  const NUMBERED = /^(DI|DO|AI|AO)(\d+)$/;
  const TOKEN_KEY = 'enip-farm-token';

  const $ = (selector, root = document) => root.querySelector(selector);
  const cards = $('#cards'), sizer = $('#sizer'), filterInput = $('#filter'), showSelect = $('#show');
  const countLabel = $('#count'), streamBadge = $('#stream'), messageLine = $('#message'), log = $('#log');
  const template = $('#card-template');
  const sleep = ms => new Promise(resolve => setTimeout(resolve, ms));

  function el(tag, className, text) {
    const element = document.createElement(tag);
    if (className) element.className = className;
    if (text !== undefined) element.textContent = text;
    return element;
  }

  function say(text, ok = false) {
    messageLine.textContent = text;
    messageLine.className = ok ? 'ok' : '';
  }

  // -- the token and the API ------------------------------------------------------------------------

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

  class ApiError extends Error {
    constructor(status, detail) { super(detail); this.status = status; }
  }

  async function api(path, options = {}) {
    for (let attempt = 0; ; attempt++) {
      const used = token;
      const headers = {};
      if (used) headers.Authorization = 'Bearer ' + used;
      let body;
      if (options.json !== undefined) {
        headers['Content-Type'] = 'application/json';
        body = JSON.stringify(options.json);
      }
      // timeoutMs: a request the browser holds (e.g. across a network change of the host) fails then
      const signal = options.timeoutMs ? AbortSignal.timeout(options.timeoutMs) : undefined;
      const response = await fetch(path, { method: options.method || 'GET', headers, body, cache: 'no-store', signal });
      if (response.status === 401 && attempt < 3 && (token !== used || await askToken())) continue;
      if (!response.ok && !(options.answers || []).includes(response.status)) {  // answers: statuses with a body
        let detail = response.statusText;
        try {
          const answer = await response.json();
          detail = typeof answer.detail === 'string' ? answer.detail
            : (answer.detail || []).map(item => `${(item.loc || []).slice(1).join('.')}: ${item.msg}`).join('; ');
        } catch (error) { /* not JSON */ }
        throw new ApiError(response.status, `${response.status} ${detail}`);
      }
      return options.stream ? response : response.json();
    }
  }

  const devicePath = name => 'devices/' + encodeURIComponent(name);

  // -- the model ------------------------------------------------------------------------------------

  const devices = [];  // configuration order
  const byName = new Map();
  const rendered = new Map();  // name -> card element, the cards in the DOM
  let filtered = [];
  let layoutDirty = true, filterDirty = true;
  const dirty = new Set();  // devices whose card needs an update
  const pendingLog = [];
  let lostSinceFrame = 0;

  function addDevice(info) {
    const device = {
      name: info.name, info,
      search: [info.name, info.address, info.model, ...info.addons, info.identity.product_name]
        .join(' ').toLowerCase(),
      signals: null,  // [{name, type, role, value}] once a snapshot came
      index: new Map(),  // signal name -> entry of signals
      changedAt: new Map(),  // signal name -> monotonic time of the event that last set it
      state: null, stale: true,
      connected: info.connections.length > 0, faulted: info.faults.length > 0,
      card: null, changed: new Set(), full: true,
    };
    devices.push(device);
    byName.set(device.name, device);
  }

  function applyState(snapshot) {
    const device = byName.get(snapshot.name);
    if (!device) return;
    const names = snapshot.signals.map(s => s.name).join('\n');
    if (!device.signals || device.signalNames !== names) {
      device.signals = snapshot.signals.map(s => ({ ...s }));
      device.signalNames = names;
      device.index = new Map(device.signals.map(s => [s.name, s]));
      device.changedAt.clear();
      device.full = true;
    } else {
      for (const s of snapshot.signals) {
        const at = device.changedAt.get(s.name);
        if (at !== undefined && at >= snapshot.monotonic) continue;  // an event newer than the snapshot set it
        device.changedAt.delete(s.name);
        const entry = device.index.get(s.name);
        if (entry.value !== s.value) {
          entry.value = s.value;
          device.changed.add(s.name);
        }
      }
    }
    const wasShown = passes(device);
    device.state = snapshot;
    device.stale = false;
    device.connected = snapshot.connections.length > 0;
    device.faulted = snapshot.faults.length > 0;
    device.stateDirty = true;
    if (passes(device) !== wasShown) filterDirty = true;
    dirty.add(device);
    schedule();
  }

  function applyIo(event) {
    const device = byName.get(event.device);
    if (!device || !device.signals) return;  // its first snapshot will have it
    for (const [name, change] of Object.entries(event.signals)) {
      const entry = device.index.get(name);
      if (!entry) continue;
      entry.value = change.new;
      device.changedAt.set(name, event.monotonic);
      device.changed.add(name);
    }
    dirty.add(device);
    schedule();
  }

  // -- snapshots: on appearing, on events that change a device's state, and every POLL_MS ---------------

  const wanted = new Set();
  let fetching = false;

  function requestState(list) {
    for (const device of list) wanted.add(device.name);
    if (!fetching) fetchStates();
  }

  async function fetchStates() {
    fetching = true;
    try {
      while (wanted.size) {
        const names = [...wanted].slice(0, STATE_BATCH);
        for (const name of names) wanted.delete(name);
        const query = names.map(name => 'device=' + encodeURIComponent(name)).join('&');
        try {
          for (const snapshot of await api('state?' + query)) applyState(snapshot);
        } catch (error) {
          say(`state: ${error.message}`);
          await sleep(RETRY_MS);
        }
      }
    } finally {
      fetching = false;
    }
  }

  setInterval(() => {
    if (!document.hidden && rendered.size) requestState([...rendered.keys()].map(name => byName.get(name)));
  }, POLL_MS);

  // -- the event stream ---------------------------------------------------------------------------------

  function setStream(text, className = '') {
    streamBadge.textContent = text;
    streamBadge.className = 'badge ' + className;
  }

  function handleBlock(block) {
    let kind = 'message', data = '';
    for (const line of block.split('\n')) {
      if (line.startsWith('event: ')) kind = line.slice(7);
      else if (line.startsWith('data: ')) data += line.slice(6);
    }
    if (!data) return;  // a comment (keep-alive)
    const payload = JSON.parse(data);
    if (kind === 'lost') {
      lostSinceFrame += payload.lost;
      for (const device of devices) device.stale = true;  // re-read what is on screen
      requestState([...rendered.keys()].map(name => byName.get(name)));
      schedule();
      return;
    }
    if (payload.kind === 'io') applyIo(payload);
    else if (REFRESH_KINDS.has(payload.kind)) {
      const device = byName.get(payload.device);
      if (device) {
        if (payload.kind === 'fault injected' && !device.faulted) { device.faulted = true; filterDirty = true; }
        if (payload.kind === 'connection opened' && !device.connected) { device.connected = true; filterDirty = true; }
        device.stale = true;
        if (device.card) requestState([device]);
      }
    }
    if (!logPause.checked && (payload.kind !== 'io' || logIo.checked)) pendingLog.push(payload);
    if (payload.kind !== 'io') {
      if (liveKeys && liveKeys.size < 100000) liveKeys.add(eventKey(payload));
      for (const listener of listeners) listener(payload);
    }
    schedule();
  }

  async function stream() {
    for (;;) {
      let retry = RETRY_MS;
      try {
        setStream('connecting');
        const response = await api('events?exclude_kind=request', { stream: true });
        setStream('live', 'live');
        for (const listener of listeners) listener({ kind: 'live' });
        for (const device of devices) device.stale = true;  // events may have been missed: re-read
        requestState([...rendered.keys()].map(name => byName.get(name)));
        const reader = response.body.getReader();
        const decoder = new TextDecoder();
        let buffer = '';
        for (;;) {
          const { value, done } = await reader.read();
          if (done) break;
          buffer += decoder.decode(value, { stream: true });
          let end;
          while ((end = buffer.indexOf('\n\n')) >= 0) {
            const block = buffer.slice(0, end);
            buffer = buffer.slice(end + 2);
            handleBlock(block);
          }
        }
        setStream('ended', 'down');
      } catch (error) {
        setStream(error.status === 503 ? 'busy' : 'down', 'down');
        if (error.status === 503) retry = 5000;
        if (error.status && error.status !== 503) say(`events: ${error.message}`);
      }
      await sleep(retry);
    }
  }

  // -- cards ----------------------------------------------------------------------------------------

  function format(value) {
    return typeof value === 'number' && !Number.isInteger(value) ? value.toFixed(3).replace(/\.?0+$/, '') : String(value);
  }

  // The identity line, one span a field; a catalogue placeholder nobody has published (listed in the
  // device's `unverified` as MODEL.identity.FIELD) is marked as such, not shown as plain fact.
  const IDENTITY_FIELDS = [['product_name', ''], ['vendor_id', 'vendor '], ['device_type', 'type '],
                           ['product_code', 'code '], ['revision', 'rev '], ['serial_number', 'serial ']];

  function fillIdentity(line, info) {
    const unverified = new Set(info.unverified || []);
    IDENTITY_FIELDS.forEach(([field, label], i) => {
      const value = info.identity[field];
      const span = el('span', 'field', Array.isArray(value) ? value.join('.') : String(value));
      span.dataset.field = field;
      if (unverified.has(`${info.model}.identity.${field}`)) {
        span.classList.add('unverified');
        span.title = 'unverified placeholder';
      }
      line.append(i ? ' · ' + label : label, span);
    });
  }

  function buildCard(device) {
    const card = template.content.firstElementChild.cloneNode(true);
    const info = device.info, identity = info.identity;
    card.dataset.device = device.name;
    $('.name', card).textContent = device.name;
    $('.address', card).textContent = info.address;
    $('.model', card).textContent = [info.model, ...info.addons].join(' + ')
      + (info.shard_up === false ? ` \u00b7 shard ${info.shard} down` : '');  // the fleet API over shards
    fillIdentity($('.identity', card), info);
    const kinds = $('.fault-kind', card);
    for (const kind of FAULT_KINDS) kinds.appendChild(el('option', '', kind));
    $('.fault-param', card).placeholder = PARAM_HINT[kinds.value] || '';
    device.card = card;
    device.elements = null;
    device.connKey = device.faultKey = null;
    device.full = true;
    device.stateDirty = true;
    return card;
  }

  function signalElement(signal, labelled) {
    const input = signal.role === 'input';
    if (signal.type === 'DI' || signal.type === 'DO') {
      const numbered = NUMBERED.exec(signal.name);
      const led = el('span', 'led ' + (input ? 'in' : 'out'), numbered ? numbered[2] : '');
      led.dataset.signal = signal.name;
      return [led, led];
    }
    const number = el('span', 'num');
    number.dataset.signal = signal.name;
    if (!labelled) return [number, number];
    const box = el('span', 'value');
    box.appendChild(el('span', 'label', signal.name));
    box.appendChild(number);
    return [box, number];
  }

  function showSignal(element, signal) {
    if (element.classList.contains('led')) {
      element.classList.toggle('on', Boolean(signal.value));
      element.title = `${signal.name} = ${signal.value}` + (signal.role === 'input' ? ' (click to toggle)' : '');
    } else {
      element.textContent = format(signal.value);
      element.title = signal.role === 'input' ? `${signal.name}: click to set` : signal.name;
    }
  }

  function fillSignals(device) {
    const io = $('.io', device.card);
    io.textContent = '';
    const elements = new Map();
    const groups = new Map();
    let named = null;
    for (const signal of device.signals) {
      const numbered = NUMBERED.exec(signal.name);
      const [element, target] = signalElement(signal, Boolean(numbered));
      target.classList.add(signal.role === 'input' ? 'in' : 'out');
      elements.set(signal.name, target);
      showSignal(target, signal);
      if (numbered) {
        let group = groups.get(numbered[1]);
        if (!group) {
          const row = el('div', 'group');
          row.appendChild(el('span', 'label', numbered[1]));
          group = el('div', target === element && element.classList.contains('led') ? 'leds' : 'values');
          row.appendChild(group);
          io.appendChild(row);
          groups.set(numbered[1], group);
        }
        group.appendChild(element);
      } else {
        if (!named) {
          named = el('table', 'named');
          io.appendChild(named);
        }
        const row = named.insertRow();
        row.insertCell().appendChild(el('span', 'muted', signal.type));
        row.insertCell().appendChild(el('span', 'sig-name', signal.name));
        row.insertCell().appendChild(element);
      }
    }
    if (!device.signals.length) io.appendChild(el('span', 'muted', 'no I/O signals'));
    device.elements = elements;
  }

  function showState(device) {
    const card = device.card, state = device.state;
    card.classList.toggle('faulted', device.faulted);
    if (!state) return;
    const status = state.status, mode = status & 0x00f0;
    const led = $('.state-led', card);
    led.className = 'state-led' + (mode === 0x60 ? ' run' : mode === 0x70 ? ' idle' : '');
    led.title = `Identity status 0x${status.toString(16).padStart(4, '0')}`;
    const counters = state.counters;
    const connKey = JSON.stringify([state.connections, state.owners, counters]);
    if (connKey !== device.connKey) {  // the DOM changes only when what it shows does
      device.connKey = connKey;
      const conn = $('.conn', card);
      conn.textContent = '';
      const head = el('div');
      head.append(`${state.connections.length} connection${state.connections.length === 1 ? '' : 's'}`);
      if (state.owners.length) {
        head.append(' · owner ');
        head.appendChild(el('span', 'owner', state.owners.join(', ')));
      }
      head.append(` · O→T ${counters.o_t_packets} T→O ${counters.t_o_packets} · timeouts ` +
        `${counters.connection_timeouts} · TCP ${counters.tcp_connections} · sessions ${counters.sessions}`);
      conn.appendChild(head);
      for (const c of state.connections) {
        conn.appendChild(el('div', '', `${c.kind} from ${c.originator}, RPI ${c.o_t_rpi_us / 1000}/` +
          `${c.t_o_rpi_us / 1000} ms, ${c.received} received` + (c.multicast ? ', multicast' : '')));
      }
    }
    const faults = state.faults.map(fault => Object.entries(fault).filter(([key]) => key !== 'age_s' &&
      (key !== 'delay_ms' || fault.kind === 'delay')));
    const faultKey = JSON.stringify(faults);
    if (faultKey === device.faultKey) return;
    device.faultKey = faultKey;
    const active = $('.active', card);
    active.textContent = '';
    for (const entries of faults) {
      const kind = entries.find(([key]) => key === 'kind')[1];
      const details = entries.filter(([key]) => key !== 'kind').map(([key, value]) => `${key} ${value}`);
      const chip = el('span', 'chip', kind + (details.length ? ` (${details.join(', ')})` : ''));
      const clear = el('button', 'clear', '×');
      clear.type = 'button';
      clear.title = `clear ${kind}`;
      clear.dataset.kind = kind;
      chip.appendChild(clear);
      active.appendChild(chip);
    }
  }

  function updateCard(device) {
    if (!device.card) return;
    if (device.signals && (device.full || !device.elements)) {
      fillSignals(device);
      device.full = false;
      device.changed.clear();
    } else if (device.elements) {
      for (const name of device.changed) {
        const element = device.elements.get(name);
        if (element) showSignal(element, device.index.get(name));
      }
      device.changed.clear();
    }
    if (device.stateDirty) {
      showState(device);
      device.stateDirty = false;
    }
  }

  // -- layout: only the cards on screen ---------------------------------------------------------------

  // Words of the filter: each must be in the device's name, address, model, add-ons or product
  // name; `=name` is that device only (a tile of the overview opens its card so).
  function filterWords() {
    return filterInput.value.toLowerCase().split(/\s+/).filter(Boolean);
  }

  function matches(device, words) {
    return words.every(word => word[0] === '=' ? device.name.toLowerCase() === word.slice(1)
      : device.search.includes(word));
  }

  function passes(device) {
    const show = showSelect.value;
    return show === 'all' || (show === 'connected' ? device.connected : device.faulted);
  }

  function applyFilter() {
    const words = filterWords();
    filtered = devices.filter(device => passes(device) && matches(device, words));
    countLabel.textContent = `${filtered.length} of ${devices.length} devices`;
    filterDirty = false;
    layoutDirty = true;
  }

  function layout() {
    layoutDirty = false;
    const columns = Math.max(1, Math.floor((cards.clientWidth - GAP) / (CARD_W + GAP)));
    const rows = Math.ceil(filtered.length / columns);
    sizer.style.height = `${rows * (CARD_H + GAP) + GAP}px`;
    const top = cards.scrollTop, height = cards.clientHeight;
    const first = Math.max(0, Math.floor(top / (CARD_H + GAP)) - BUFFER_ROWS);
    const last = Math.min(rows - 1, Math.floor((top + height) / (CARD_H + GAP)) + BUFFER_ROWS);
    const places = new Map();
    for (let row = first; row <= last; row++) {
      for (let column = 0; column < columns; column++) {
        const index = row * columns + column;
        if (index >= filtered.length) break;
        places.set(filtered[index].name, [row, column]);
      }
    }
    for (const [name, card] of rendered) {
      if (!places.has(name)) {
        card.remove();
        rendered.delete(name);
        byName.get(name).card = null;
      }
    }
    const unknown = [];
    for (const [name, [row, column]] of places) {
      const device = byName.get(name);
      if (!device.card) {
        sizer.appendChild(buildCard(device));
        rendered.set(name, device.card);
        updateCard(device);
      }
      if (device.stale) unknown.push(device);
      device.card.style.transform = `translate(${GAP + column * (CARD_W + GAP)}px, ${GAP + row * (CARD_H + GAP)}px)`;
    }
    if (unknown.length) requestState(unknown);
  }

  // -- the event log ----------------------------------------------------------------------------------

  const logIo = $('#log-io'), logPause = $('#log-pause');

  function detailText(detail) {
    // a fault's parameters come as an object: kind=delay delay_ms=250
    if (detail && typeof detail === 'object') {
      return Object.entries(detail).map(([key, value]) => `${key}=${value}`).join(' ');
    }
    return detail || '';
  }

  function clock(seconds) {
    const time = new Date(seconds * 1000);
    return time.toLocaleTimeString([], { hour12: false }) + '.' + String(time.getMilliseconds()).padStart(3, '0');
  }

  function logLine(className, text) {
    const item = el('li', className, text);
    log.insertBefore(item, log.firstChild);
  }

  function flushLog() {  // at most LOG_PER_FRAME lines a frame: the rest is counted, not drawn
    if (lostSinceFrame) {
      logLine('lost', `${lostSinceFrame} events lost (this page fell behind): re-reading`);
      lostSinceFrame = 0;
    }
    if (!pendingLog.length) return;
    const batch = shownInLog(pendingLog);
    pendingLog.length = 0;
    const skipped = batch.length - LOG_PER_FRAME;
    if (skipped > 0) logLine('t', `… ${skipped} more events not shown`);
    log.insertBefore(logItems(batch.slice(Math.max(0, skipped))), log.firstChild);
    while (log.childElementCount > LOG_MAX) log.lastElementChild.remove();
  }

  function shownInLog(events) {  // those of the devices the filter shows
    const words = filterWords();
    return events.filter(event => {
      const device = byName.get(event.device);
      return !words.length || !device || matches(device, words);
    });
  }

  function logItems(events) {  // oldest first in, newest first out
    const fragment = document.createDocumentFragment();
    for (let i = events.length - 1; i >= 0; i--) {
      const event = events[i];
      const item = el('li');
      item.appendChild(el('span', 't', clock(event.time) + ' '));
      const name = el('span', 'd', event.device);
      name.dataset.device = event.device;
      item.appendChild(name);
      const kind = event.kind === 'io' ? 'k k-io' : event.kind.startsWith('fault') ? 'k k-fault' : 'k';
      item.appendChild(el('span', kind, ` ${event.kind} `));
      item.append(detailText(event.detail));
      fragment.appendChild(item);
    }
    return fragment;
  }

  // Events from before the page opened (GET overview?events=N, read once the stream is live), put
  // below the live ones; those the stream also brought (the read and the stream overlap) once.
  const eventKey = event => `${event.monotonic} ${event.device} ${event.kind}`;
  let liveKeys = new Set();  // the live events logged until the history came

  function addHistory(events) {
    const seen = liveKeys || new Set();
    liveKeys = null;
    const older = events.filter(event => !seen.has(eventKey(event)));
    const batch = shownInLog(older).slice(-LOG_MAX);
    if (!batch.length) return;
    log.appendChild(logItems(batch));
    while (log.childElementCount > LOG_MAX) log.lastElementChild.remove();
  }

  // -- one frame for all DOM work ------------------------------------------------------------------------

  let scheduled = false;

  function schedule() {
    if (!scheduled) {
      scheduled = true;
      requestAnimationFrame(frame);
    }
  }

  function frame() {
    scheduled = false;
    if (filterDirty) applyFilter();
    if (layoutDirty) layout();
    for (const device of dirty) updateCard(device);
    dirty.clear();
    flushLog();
  }

  // -- what the user does -------------------------------------------------------------------------------

  async function write(device, signals) {
    try {
      await api(devicePath(device.name) + '/io', { method: 'PUT', json: { signals } });
      say('');
    } catch (error) {
      say(`${device.name}: ${error.message}`);
    }
  }

  function editValue(device, element) {
    const signal = device.index.get(element.dataset.signal);
    const input = el('input', 'edit');
    input.type = 'number';
    input.step = 'any';
    input.value = signal.value;
    element.replaceWith(input);
    input.focus();
    input.select();
    let done = false;
    const finish = commit => {
      if (done) return;
      done = true;
      input.replaceWith(element);
      if (commit && input.value !== '') write(device, { [signal.name]: Number(input.value) });
    };
    input.addEventListener('keydown', event => {
      if (event.key === 'Enter') finish(true);
      else if (event.key === 'Escape') finish(false);
    });
    input.addEventListener('blur', () => finish(false));
  }

  sizer.addEventListener('click', event => {
    const card = event.target.closest('.card');
    if (!card) return;
    const device = byName.get(card.dataset.device);
    const clear = event.target.closest('button.clear');
    if (clear) {
      api(`${devicePath(device.name)}/faults?kind=${encodeURIComponent(clear.dataset.kind)}`, { method: 'DELETE' })
        .then(() => requestState([device]), error => say(`${device.name}: ${error.message}`));
      return;
    }
    if (event.target.closest('button.power-cycle')) {
      api(devicePath(device.name) + '/reset', { method: 'POST', json: { type: 0 } }).then(done => {
        say(`${device.name}: power cycled, answering again in ${done.reset_time_s} s`, true);
        requestState([device]);
      }, error => say(`${device.name}: ${error.message}`));
      return;
    }
    const target = event.target.closest('[data-signal]');
    if (!target || !device.index.has(target.dataset.signal)) return;
    const signal = device.index.get(target.dataset.signal);
    if (signal.role !== 'input') return;
    if (target.classList.contains('led')) write(device, { [signal.name]: signal.value ? 0 : 1 });
    else editValue(device, target);
  });

  sizer.addEventListener('change', event => {
    if (!event.target.classList.contains('fault-kind')) return;
    const param = $('.fault-param', event.target.closest('.card'));
    param.placeholder = PARAM_HINT[event.target.value] || '';
  });

  function faultRequest(kind, param, duration) {
    const body = { kind };
    const numbers = param.trim().split(/[\s,]+/).filter(Boolean).map(Number);
    if (kind === 'delay') {
      body.delay_ms = numbers[0];
      if (numbers.length > 1) body.max_delay_ms = numbers[1];
    } else if (kind === 'status') {
      [body.service, body.status] = numbers;
    }
    if (duration.trim()) body.duration_s = Number(duration);
    return body;
  }

  sizer.addEventListener('submit', event => {
    event.preventDefault();
    const form = event.target, card = form.closest('.card');
    const device = byName.get(card.dataset.device);
    const body = faultRequest($('.fault-kind', form).value, $('.fault-param', form).value,
      $('.fault-duration', form).value);
    api(devicePath(device.name) + '/faults', { method: 'POST', json: body }).then(active => {
      say(`${device.name}: ${active.map(fault => fault.kind).join(', ')} active`, true);
      requestState([device]);
    }, error => say(`${device.name}: ${error.message}`));
  });

  $('#log').addEventListener('click', event => {
    const name = event.target.dataset && event.target.dataset.device;
    if (!name) return;
    filterInput.value = name;
    filterDirty = true;
    schedule();
  });

  for (const type of ['input', 'change']) filterInput.addEventListener(type, () => { filterDirty = true; schedule(); });
  showSelect.addEventListener('change', () => { filterDirty = true; schedule(); });
  cards.addEventListener('scroll', () => { layoutDirty = true; schedule(); }, { passive: true });
  window.addEventListener('resize', () => { layoutDirty = true; schedule(); });

  // -- what overview.js uses ----------------------------------------------------------------------------

  function showDevice(name) {  // that device's card alone, at the top
    filterInput.value = '=' + name;
    showSelect.value = 'all';
    cards.scrollTop = 0;
    filterDirty = true;
    schedule();
  }

  const listeners = [];  // called with every event of the stream but `io`, and {kind: 'live'}
  window.enipFarm = { api, say, showDevice, addHistory, onEvent: listener => listeners.push(listener) };

  // -- start ------------------------------------------------------------------------------------------

  async function start() {
    for (;;) {
      try {
        for (const info of await api('devices')) addDevice(info);
        break;
      } catch (error) {
        say(`devices: ${error.message}`);
        await sleep(RETRY_MS * 2);
      }
    }
    filterDirty = true;
    schedule();
    document.body.dataset.ready = 'true';
    stream();
  }

  start();
})();
