// enip-farm dashboard: every device of the farm as a card, driven through the HTTP API; ES modules
// without a build step, each with one job (and its browser test, tests/test_dashboard_modules.py):
//   api.js           the HTTP API: JSON, errors, the token
//   events.js        the event stream (GET events): parsing, reconnecting, the #stream badge
//   devices.js       the devices and their snapshots (GET devices, GET state), "io" events applied
//   table.js         the cards: filter, "which devices", only those on screen in the DOM
//   io-panel.js      a card's signals: LEDs and values, clicks and typed values written
//   faults-panel.js  a card's faults: kinds from GET fault-kinds, inject, clear, power cycle
//   event-log.js     the events panel
//   overview.js      the plant's overview: tiles by state, counts, the I/O thread's health
//   inspect.js       a device's inspector: its signal timeline (timeline.js) and its connections'
//                    measured O->T intervals (histogram.js, from GET report); svg.js draws
//   frame.js, dom.js one animation frame for all DOM work; DOM helpers and the message line
// This module starts them and hands the stream's events to each.

import { $ } from './dom.js';
import { allStale, applyEvent, byName, loadDevices, poll, requestState } from './devices.js';
import * as eventLog from './event-log.js';
import { follow } from './events.js';
import { attach as attachFaults, loadKinds } from './faults-panel.js';
import * as inspect from './inspect.js';
import { clicked } from './io-panel.js';
import * as overview from './overview.js';
import * as table from './table.js';

function onLive() {
  overview.onEvent({ kind: 'live' });
  allStale();
}

function onEvent(kind, event) {
  if (kind === 'lost') {  // the page fell behind: re-read what is on screen
    eventLog.addLost(event.lost);
    allStale();
    return;
  }
  applyEvent(event);
  eventLog.addEvent(event);
  if (event.kind !== 'io') overview.onEvent(event);
}

async function start() {
  table.start();
  eventLog.start();
  const sizer = $('#sizer');
  attachFaults(sizer, byName, device => requestState([device]));
  sizer.addEventListener('click', event => {
    const card = event.target.closest('.card');
    if (card && event.target.closest('.inspect')) inspect.open(card.dataset.device);
    else if (card) clicked(byName.get(card.dataset.device), event.target);
  });
  overview.start();
  inspect.start();
  await Promise.all([loadKinds(), loadDevices()]);
  table.refilter();
  document.body.dataset.ready = 'true';
  poll();
  follow('events?exclude_kind=request', { onLive, onEvent });
}

start();
