// The device table: every device as a card of fixed size, only those on screen (and a row either
// side) in the DOM; the filter (words of name, address, model, add-ons, product name; `=name` is
// that device alone) and the "which devices" menu (all, with connections, with faults); the card's
// head, identity line, state LED and connections line. Its I/O panel (io-panel.js) and faults
// panel (faults-panel.js) draw the rest of the card. All DOM work happens in the page's frame.

import { $, el, plural } from './dom.js';
import { byName, devices, dirty, requestState, table } from './devices.js';
import { drawFaults, fillForm } from './faults-panel.js';
import { onFrame, schedule } from './frame.js';
import { drawSignals } from './io-panel.js';

const CARD_W = 360, CARD_H = 380, GAP = 10, BUFFER_ROWS = 1;

const cards = $('#cards'), sizer = $('#sizer'), filterInput = $('#filter'), showSelect = $('#show');
const countLabel = $('#count'), template = $('#card-template');
const rendered = new Map();  // name -> card element, the cards in the DOM
let filtered = [];
let layoutDirty = true, filterDirty = true;

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
  const info = device.info;
  card.dataset.device = device.name;
  $('.name', card).textContent = device.name;
  $('.address', card).textContent = info.address;
  $('.model', card).textContent = [info.model, ...info.addons].join(' + ')
    + (info.shard_up === false ? ` \u00b7 shard ${info.shard} down` : '')  // the fleet's router over shards
    + (info.worker_up === false ? ` \u00b7 worker ${info.worker} down` : '');  // or over workers
  fillIdentity($('.identity', card), info);
  fillForm(card);
  device.card = card;
  device.elements = null;
  device.connKey = device.faultKey = null;
  device.full = true;
  device.stateDirty = true;
  return card;
}

function drawState(device) {
  const card = device.card, state = device.state;
  card.classList.toggle('faulted', device.faulted);
  if (!state) return;
  const status = state.status, mode = status & 0x00f0;
  const led = $('.state-led', card);
  led.className = 'state-led' + (mode === 0x60 ? ' run' : mode === 0x70 ? ' idle' : '');
  led.title = `Identity status 0x${status.toString(16).padStart(4, '0')}`;
  const counters = state.counters, open = state.open;
  const connKey = JSON.stringify([state.connections, state.owners, counters, open]);
  if (connKey !== device.connKey) {  // the DOM changes only when what it shows does
    device.connKey = connKey;
    const conn = $('.conn', card);
    conn.textContent = '';
    const head = el('div');
    // what is open now, then the running totals, labelled as such (they read as open beside "0 connections")
    head.append(`${plural(state.connections.length, 'connection')} · TCP ${open.tcp} open · ` +
      `${plural(open.sessions, 'session')} open`);
    if (state.owners.length) {
      head.append(' · owner ');
      head.appendChild(el('span', 'owner', state.owners.join(', ')));
    }
    const totals = el('div', 'totals', `since start: TCP ${counters.tcp_connections}, sessions ${counters.sessions}, ` +
      `O→T ${counters.o_t_packets}, T→O ${counters.t_o_packets}, timeouts ${counters.connection_timeouts}`);
    conn.appendChild(head);
    conn.appendChild(totals);
    for (const c of state.connections) {
      conn.appendChild(el('div', '', `${c.kind} from ${c.originator}, RPI ${c.o_t_rpi_us / 1000}/` +
        `${c.t_o_rpi_us / 1000} ms, ${c.received} received` + (c.multicast ? ', multicast' : '')));
    }
  }
  drawFaults(device);
}

function updateCard(device) {
  if (!device.card) return;
  drawSignals(device);
  if (device.stateDirty) {
    drawState(device);
    device.stateDirty = false;
  }
}

// -- the filter -----------------------------------------------------------------------------------------

export function filterWords() {
  return filterInput.value.toLowerCase().split(/\s+/).filter(Boolean);
}

export function matches(device, words) {
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
  countLabel.textContent = `${filtered.length} of ${plural(devices.length, 'device')}`;
  filterDirty = false;
  layoutDirty = true;
}

export function refilter() {
  filterDirty = true;
  schedule();
}

// -- layout: only the cards on screen -------------------------------------------------------------------

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

// That device's card alone, at the top (a tile of the overview, a name in the events panel).
export function showDevice(name, exact = true) {
  filterInput.value = exact ? '=' + name : name;
  if (exact) showSelect.value = 'all';
  if (exact) cards.scrollTop = 0;
  refilter();
}

export function start() {
  table.shown = () => [...rendered.keys()].map(name => byName.get(name));
  table.flagsChanged = () => { if (showSelect.value !== 'all') refilter(); };
  onFrame(() => {
    if (filterDirty) applyFilter();
    if (layoutDirty) layout();
    for (const device of dirty) updateCard(device);
    dirty.clear();
  });
  for (const type of ['input', 'change']) filterInput.addEventListener(type, refilter);
  showSelect.addEventListener('change', refilter);
  cards.addEventListener('scroll', () => { layoutDirty = true; schedule(); }, { passive: true });
  window.addEventListener('resize', () => { layoutDirty = true; schedule(); });
  refilter();
}
