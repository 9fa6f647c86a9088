// enip-farm dashboard: the plant's overview, every device as a small tile coloured by its state
// (idle, class-1 running, timed out, faulted), the count in each state on top, a filter of its own
// (words of name, address, model, add-ons; a count toggles a state), and a click on a tile opens
// that device's card below (table.js, `showDevice`).
//
// Data: GET overview (every device's state in one answer, control/overview.py) at load, every
// POLL_MS, and REFRESH_MS after a stream event that can change a state (connections, faults,
// resets); what such an event surely means (a fault injected: faulted; a class-1 connection opened:
// running) shows at once, and the read after it confirms it. Once the stream is live, the recent
// events (overview?events=N) go to the events panel. The counts are the tiles', so they agree.
// GET health's `cyclic_io` ({running, errors}), when the farm gives it, shows a banner while the
// class-1 I/O thread does not run (a farm without GET health, or without the field: no banner).
// All DOM work happens in one animation frame, however many reads and events came since the last.
// main.js hands it the stream's events (`onEvent`, and {kind: 'live'} when the stream is live).

import { api } from './api.js';
import { $, plural, say, sleep } from './dom.js';
import { addHistory } from './event-log.js';
import { showDevice } from './table.js';

const STATES = ['idle', 'running', 'timed_out', 'faulted'];
const LABELS = { idle: 'idle', running: 'class-1 running', timed_out: 'timed out', faulted: 'faulted' };
const POLL_MS = 2000, REFRESH_MS = 250, HEALTH_MS = 2000, RETRY_MS = 1000, HISTORY = 200, TIMEOUT_MS = 10000;
const NAMED_MAX = 120;  // up to this many devices a tile shows its name; beyond, a small square
const STATE_KINDS = /^(connection |fault |reset|safety )/;

const tilesBox = $('#tiles'), tileFilter = $('#tile-filter'), shownLabel = $('#tiles-shown');
const banner = $('#io-banner');
const tiles = new Map();  // name -> {info, element}
let names = '';  // the devices the tiles were built for, in order
let stateFilter = null;  // a state, or null for all
let selected = null;
let snapshot = null;  // read, not yet drawn
const guessed = new Set();  // tiles an event recoloured, not yet drawn
let filterDirty = true, framed = false;

// -- tiles ------------------------------------------------------------------------------------------

function tileTitle(info) {
  const lines = [`${info.name}  ${info.address}`, [info.model, ...info.addons].join(' + '), LABELS[info.state]];
  if (info.io_connections) lines.push(`${info.io_connections} class-1 connection(s)`);
  if (info.timeouts) lines.push(`${info.timeouts} connection timeout(s)`);
  if (info.faults.length) lines.push(`faults: ${info.faults.join(', ')}`);
  return lines.join('\n');
}

function paint(tile) {
  tile.element.className = `tile s-${tile.info.state}` + (tile.info.name === selected ? ' selected' : '');
  tile.element.title = tileTitle(tile.info);
}

function buildTiles(devices) {
  const fragment = document.createDocumentFragment();
  tiles.clear();
  for (const info of devices) {
    const element = document.createElement('span');
    element.dataset.device = info.name;
    element.setAttribute('role', 'button');
    if (devices.length <= NAMED_MAX) element.textContent = info.name;
    const tile = { info, element, search: searchText(info) };
    tiles.set(info.name, tile);
    paint(tile);
    fragment.appendChild(element);
  }
  tilesBox.classList.toggle('named', devices.length <= NAMED_MAX);
  tilesBox.replaceChildren(fragment);
}

function searchText(info) {
  return [info.name, info.address, info.model, ...info.addons].join(' ').toLowerCase();
}

function updateTiles(devices) {  // the DOM changes only where a tile's state or figures did
  for (const info of devices) {
    const tile = tiles.get(info.name);
    const was = tile.info;
    tile.info = info;
    if (was.state !== info.state || was.io_connections !== info.io_connections || was.timeouts !== info.timeouts
        || was.faults.join() !== info.faults.join()) paint(tile);
  }
}

function showCounts() {
  const counts = Object.fromEntries(STATES.map(state => [state, 0]));
  for (const tile of tiles.values()) counts[tile.info.state]++;
  for (const state of STATES) {
    const button = $(`#counts [data-state="${state}"]`);
    button.querySelector('b').textContent = counts[state];
    button.classList.toggle('on', stateFilter === state);
  }
}

function applyTileFilter() {
  const words = tileFilter.value.toLowerCase().split(/\s+/).filter(Boolean);
  let shown = 0;
  for (const tile of tiles.values()) {
    const visible = (!stateFilter || tile.info.state === stateFilter) && words.every(w => tile.search.includes(w));
    if (tile.element.hidden === visible) tile.element.hidden = !visible;
    shown += visible;
  }
  shownLabel.textContent = shown === tiles.size ? plural(tiles.size, 'device') : `${shown} of ${tiles.size} shown`;
}

function render(read) {
  const order = read.devices.map(info => info.name).join('\n');
  if (order !== names) {
    buildTiles(read.devices);
    names = order;
    filterDirty = true;
  } else {
    updateTiles(read.devices);
  }
}

function draw() {  // one animation frame: the last read, the events' recolouring, the counts, the filter
  framed = false;
  if (snapshot) {
    render(snapshot);
    snapshot = null;
  }
  for (const tile of guessed) paint(tile);
  guessed.clear();
  showCounts();
  if (filterDirty || stateFilter) applyTileFilter();
  filterDirty = false;
  if (tiles.size) document.body.dataset.overview = 'complete';
}

function redraw() {
  if (!framed) {
    framed = true;
    requestAnimationFrame(draw);
  }
}

function guess(event) {  // what an event surely means, until the read it asks for says it all
  const tile = tiles.get(event.device);
  if (!tile) return;
  let state = null;
  if (event.kind === 'fault injected') state = 'faulted';
  else if (event.kind === 'connection opened' && !String(event.detail).startsWith('explicit')
           && tile.info.state !== 'faulted') state = 'running';
  if (state === null || state === tile.info.state) return;
  tile.info = { ...tile.info, state };
  guessed.add(tile);
  redraw();
}

// -- reading the overview: at load, every POLL_MS, soon after an event that changes a state -----------

let reading = null, again = false, timer = null;

async function read(events = 0) {
  while (reading) {  // one read at a time; one more after it if asked meanwhile
    if (!events) {
      again = true;
      return reading;
    }
    await reading;  // the history's read waits its turn
  }
  reading = (async () => {
    try {
      const read = await api('overview' + (events ? `?events=${events}` : ''), { timeoutMs: TIMEOUT_MS });
      snapshot = read;
      redraw();
      if (events) addHistory(read.events);
      return true;
    } catch (error) {
      say(`overview: ${error.message}`);
      return false;
    } finally {
      reading = null;
    }
  })();
  const done = await reading;
  if (again) {
    again = false;
    soon();
  }
  return done;
}

function soon(delay = REFRESH_MS) {
  if (timer === null) timer = setTimeout(() => { timer = null; read(); }, delay);
}

let historyRead = false;

export function onEvent(event) {
  if (event.kind === 'live' && !historyRead) {
    historyRead = true;
    read(HISTORY).then(done => { if (!done) historyRead = false; });
  } else if (STATE_KINDS.test(event.kind)) {
    guess(event);
    soon();
  }
}

// -- the class-1 I/O thread's health (GET health, when the farm has it) ---------------------------------

async function checkHealth() {
  let health;
  try {
    // 503: it does not serve as it should, and the answer says why
    health = await api('health', { answers: [503], timeoutMs: TIMEOUT_MS });
  } catch (error) {
    if (error.status === 404) return;  // a farm without it: no banner, and no more asking
    setTimeout(checkHealth, HEALTH_MS);
    return;
  }
  const io = health && health.cyclic_io;
  banner.hidden = !io || io.running !== false;
  if (io && io.running === false) {
    banner.textContent = `Class-1 I/O is not running (${io.errors} error${io.errors === 1 ? '' : 's'}): ` +
      'no device answers its I/O connections. See the farm\'s console.';
  }
  setTimeout(checkHealth, HEALTH_MS);
}

// -- what the user does ---------------------------------------------------------------------------------

tilesBox.addEventListener('click', event => {
  const element = event.target.closest('[data-device]');
  if (!element) return;
  const previous = tiles.get(selected);
  selected = element.dataset.device;
  if (previous) paint(previous);
  paint(tiles.get(selected));
  showDevice(selected);
});

$('#counts').addEventListener('click', event => {
  const button = event.target.closest('[data-state]');
  if (!button) return;
  stateFilter = stateFilter === button.dataset.state ? null : button.dataset.state;
  filterDirty = true;
  redraw();
});

tileFilter.addEventListener('input', () => { filterDirty = true; redraw(); });

export async function start() {
  while (!await read()) await sleep(RETRY_MS);
  setInterval(() => { if (!document.hidden) read(); }, POLL_MS);
  checkHealth();
}
