// The farm's devices as the page knows them: the list (GET devices, once), each device's snapshot
// (GET state?device=..., batched: signals with values, connections, counters, faults) when its card
// appears, after an event that changes its state, and every POLL_MS for the cards on screen; and
// the stream's "io" events, which update signals between snapshots. A snapshot carries the
// server's monotonic time, read before the images: a signal changed by an event at or after that
// time keeps the event's value. `dirty` holds the devices whose card needs drawing.

import { api } from './api.js';
import { say, sleep } from './dom.js';
import { schedule } from './frame.js';

const POLL_MS = 1000, STATE_BATCH = 40, RETRY_MS = 1000;
const REFRESH_KINDS = new Set(['connection opened', 'connection closed', 'connection timed out',
  'fault injected', 'fault cleared', 'session registered', 'session ended', 'tcp connected', 'tcp closed']);

export const devices = [];  // configuration order
export const byName = new Map();
export const dirty = new Set();
// What the device table sets: the devices with a card, and what to do when a device's
// `connected` or `faulted` changed (the table's "which devices" menu shows by them).
export const table = { shown: () => [], flagsChanged: () => {} };

export function addDevice(info) {
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
  return device;
}

export async function loadDevices() {  // until the API answers
  for (;;) {
    try {
      for (const info of await api('devices')) addDevice(info);
      return;
    } catch (error) {
      say(`devices: ${error.message}`);
      await sleep(RETRY_MS * 2);
    }
  }
}

function setFlags(device, connected, faulted) {
  if (device.connected === connected && device.faulted === faulted) return;
  device.connected = connected;
  device.faulted = faulted;
  table.flagsChanged();
}

export function applyState(snapshot) {
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
  device.state = snapshot;
  device.stale = false;
  setFlags(device, snapshot.connections.length > 0, snapshot.faults.length > 0);
  device.stateDirty = true;
  dirty.add(device);
  schedule();
}

export function applyIo(event) {
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

// An event of the stream: "io" updates signals; one that changes a device's state marks it
// stale and re-reads it if it has a card (a fault injected or a connection opened shows at once).
export function applyEvent(event) {
  if (event.kind === 'io') {
    applyIo(event);
    return;
  }
  const device = byName.get(event.device);
  if (!device || !REFRESH_KINDS.has(event.kind)) return;
  if (event.kind === 'fault injected') setFlags(device, device.connected, true);
  if (event.kind === 'connection opened') setFlags(device, true, device.faulted);
  device.stale = true;
  if (device.card) requestState([device]);
}

export function allStale() {  // events may have been missed: re-read what is on screen
  for (const device of devices) device.stale = true;
  requestState(table.shown());
}

// -- snapshots: batched, one read at a time ------------------------------------------------------------

const wanted = new Set();
let fetching = false;

export function requestState(list) {
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

export function poll() {
  setInterval(() => {
    const shown = table.shown();
    if (!document.hidden && shown.length) requestState(shown);
  }, POLL_MS);
}
