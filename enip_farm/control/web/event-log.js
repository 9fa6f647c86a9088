// The events panel: the stream's events, newest first (at most LOG_PER_FRAME drawn a frame, the
// rest counted; LOG_MAX kept), those of the devices the filter shows; "I/O" and "pause" boxes; a
// "lost" line when the page fell behind the stream; the events from before the page opened
// (`addHistory`) below the live ones, each once; a click on a device's name filters the cards to it.

import { $, el } from './dom.js';
import { byName } from './devices.js';
import { onFrame, schedule } from './frame.js';
import { filterWords, matches, showDevice } from './table.js';

const LOG_MAX = 300, LOG_PER_FRAME = 20;

const log = $('#log'), logIo = $('#log-io'), logPause = $('#log-pause');
const pending = [];
let lost = 0;
const eventKey = event => `${event.monotonic} ${event.device} ${event.kind}`;
let liveKeys = new Set();  // the live events logged until the history came

// An event's detail as text: a fault's parameters come as an object, `kind=delay delay_ms=250`.
export function detailText(detail) {
  if (detail && typeof detail === 'object') {
    return Object.entries(detail).map(([key, value]) => `${key}=${value}`).join(' ');
  }
  return detail || '';
}

export function clock(seconds) {
  const time = new Date(seconds * 1000);
  return time.toLocaleTimeString([], { hour12: false }) + '.' + String(time.getMilliseconds()).padStart(3, '0');
}

export function addEvent(event) {
  if (!logPause.checked && (event.kind !== 'io' || logIo.checked)) pending.push(event);
  if (event.kind !== 'io' && liveKeys && liveKeys.size < 100000) liveKeys.add(eventKey(event));
  schedule();
}

export function addLost(count) {
  lost += count;
  schedule();
}

function logLine(className, text) {
  log.insertBefore(el('li', className, text), log.firstChild);
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

function flush() {
  if (lost) {
    logLine('lost', `${lost} events lost (this page fell behind): re-reading`);
    lost = 0;
  }
  if (!pending.length) return;
  const batch = shownInLog(pending);
  pending.length = 0;
  const skipped = batch.length - LOG_PER_FRAME;
  if (skipped > 0) logLine('t', `… ${skipped} more events not shown`);
  log.insertBefore(logItems(batch.slice(Math.max(0, skipped))), log.firstChild);
  while (log.childElementCount > LOG_MAX) log.lastElementChild.remove();
}

// Events from before the page opened (GET overview?events=N, read once the stream is live), put
// below the live ones; those the stream also brought (the read and the stream overlap) once.
export function addHistory(events) {
  const seen = liveKeys || new Set();
  liveKeys = null;
  const batch = shownInLog(events.filter(event => !seen.has(eventKey(event)))).slice(-LOG_MAX);
  if (!batch.length) return;
  log.appendChild(logItems(batch));
  while (log.childElementCount > LOG_MAX) log.lastElementChild.remove();
}

export function start() {
  onFrame(flush);
  log.addEventListener('click', event => {
    const name = event.target.dataset && event.target.dataset.device;
    if (name) showDevice(name, false);
  });
}
