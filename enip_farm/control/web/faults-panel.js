// A card's faults panel: the active faults as chips (× clears one: DELETE devices/{name}/faults),
// and a form to inject one (POST devices/{name}/faults) of the kinds the farm lists with their
// parameters (GET fault-kinds, read once: no list of kinds here). The parameter field takes the
// kind's parameters in the order the farm lists them, separated by spaces or commas (delay:
// `800` or `200 900`, status: `0x0E 0x08`); the duration field `duration_s`. The power-cycle
// button resets the device (POST devices/{name}/reset, type 0).

import { api, devicePath } from './api.js';
import { $, el, say, sleep } from './dom.js';

const RETRY_MS = 1000;
const kinds = new Map();  // name -> {kind, summary, parameters: JSON Schema}

export async function loadKinds() {  // until the API answers
  for (;;) {
    try {
      for (const kind of await api('fault-kinds')) kinds.set(kind.kind, kind);
      return kinds;
    } catch (error) {
      say(`fault kinds: ${error.message}`);
      await sleep(RETRY_MS);
    }
  }
}

// The kind's parameters the parameter field takes, in order (`duration_s` has its own field).
export function parameterNames(kind) {
  const known = kinds.get(kind);
  return known ? Object.keys(known.parameters.properties || {}).filter(name => name !== 'duration_s') : [];
}

// The body of POST devices/{name}/faults for what the form holds.
export function faultRequest(kind, param, duration) {
  const body = { kind };
  const values = param.trim().split(/[\s,]+/).filter(Boolean).map(Number);
  parameterNames(kind).forEach((name, i) => { if (i < values.length) body[name] = values[i]; });
  if (duration.trim()) body.duration_s = Number(duration);
  return body;
}

function hint(form) {
  const kind = $('.fault-kind', form).value;
  $('.fault-kind', form).title = (kinds.get(kind) || {}).summary || '';
  $('.fault-param', form).placeholder = parameterNames(kind).join(' ');
}

export function fillForm(card) {  // a new card's kinds
  const select = $('.fault-kind', card);
  for (const kind of kinds.values()) {
    const option = el('option', '', kind.kind);
    option.title = kind.summary;
    select.appendChild(option);
  }
  hint($('.fault-form', card));
}

// The active faults as chips, redrawn only when they changed.
export function drawFaults(device) {
  const faults = device.state.faults.map(fault => Object.entries(fault).filter(([key]) => key !== 'age_s'));
  const key = JSON.stringify(faults);
  if (key === device.faultKey) return;
  device.faultKey = key;
  const active = $('.active', device.card);
  active.textContent = '';
  for (const entries of faults) {
    const kind = entries.find(([name]) => name === 'kind')[1];
    const details = entries.filter(([name]) => name !== 'kind').map(([name, value]) => `${name} ${value}`);
    const chip = el('span', 'chip', kind + (details.length ? ` (${details.join(', ')})` : ''));
    const clear = el('button', 'clear', '×');
    clear.type = 'button';
    clear.title = `clear ${kind}`;
    clear.dataset.kind = kind;
    chip.appendChild(clear);
    active.appendChild(chip);
  }
}

// Wires the panels of every card under `root`; `refresh(device)` re-reads a device's state.
export function attach(root, byName, refresh) {
  root.addEventListener('click', event => {
    const card = event.target.closest('.card');
    if (!card) return;
    const device = byName.get(card.dataset.device);
    const clear = event.target.closest('button.clear');
    if (clear) {
      api(`${devicePath(device.name)}/faults?kind=${encodeURIComponent(clear.dataset.kind)}`, { method: 'DELETE' })
        .then(() => refresh(device), error => say(`${device.name}: ${error.message}`));
    } else if (event.target.closest('button.power-cycle')) {
      api(devicePath(device.name) + '/reset', { method: 'POST', json: { type: 0 } }).then(done => {
        say(`${device.name}: power cycled, answering again in ${done.reset_time_s} s`, true);
        refresh(device);
      }, error => say(`${device.name}: ${error.message}`));
    }
  });
  root.addEventListener('change', event => {
    if (event.target.classList.contains('fault-kind')) hint(event.target.closest('.fault-form'));
  });
  root.addEventListener('submit', event => {
    event.preventDefault();
    const form = event.target;
    const device = byName.get(form.closest('.card').dataset.device);
    const body = faultRequest($('.fault-kind', form).value, $('.fault-param', form).value,
      $('.fault-duration', form).value);
    api(devicePath(device.name) + '/faults', { method: 'POST', json: body }).then(active => {
      say(`${device.name}: ${active.map(fault => fault.kind).join(', ')} active`, true);
      refresh(device);
    }, error => say(`${device.name}: ${error.message}`));
  });
}
