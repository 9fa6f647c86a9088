// A card's I/O panel: the device's signals, numbered ones (DI3, AO1) in rows of LEDs and values,
// named ones in a table; an input LED toggles on a click, an input value is typed in (Enter
// writes, Escape or leaving the field does not); writes go through PUT devices/{name}/io.

import { api, devicePath } from './api.js';
import { $, el, say } from './dom.js';

const NUMBERED = /^(DI|DO|AI|AO)(\d+)$/;

export function format(value) {
  return typeof value === 'number' && !Number.isInteger(value) ? value.toFixed(3).replace(/\.?0+$/, '') : String(value);
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

// Draw what changed of a device's signals: all of them on its first snapshot (or a new card),
// else only those changed since the last frame.
export function drawSignals(device) {
  if (device.signals && (device.full || !device.elements)) {
    fillSignals(device);
    device.full = false;
  } else if (device.elements) {
    for (const name of device.changed) {
      const element = device.elements.get(name);
      if (element) showSignal(element, device.index.get(name));
    }
  }
  device.changed.clear();
}

export async function write(device, signals) {
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

// A click on a card (`device` its device): an input LED toggles, an input value opens its field.
export function clicked(device, target) {
  const element = target.closest('[data-signal]');
  if (!element || !device.index.has(element.dataset.signal)) return;
  const signal = device.index.get(element.dataset.signal);
  if (signal.role !== 'input') return;
  if (element.classList.contains('led')) write(device, { [signal.name]: signal.value ? 0 : 1 });
  else editValue(device, element);
}
