// The inspector of one device (a card's "timeline" button): a dialog with its signal timeline over
// the last N seconds (timeline.js) and, per class-1 connection, the measured O->T intervals as a
// histogram with the verdicts (histogram.js, from GET report). While open it reads both every
// REFRESH_MS; closed, nothing.

import { api, devicePath } from './api.js';
import { $, el, say } from './dom.js';
import * as histogram from './histogram.js';
import * as timeline from './timeline.js';

export const REFRESH_MS = 1000;

const dialog = () => $('#inspect');
let current = null, timer = null;

function verdictLine(verdicts) {
  return verdicts.map(v => `${v.figure}: ${v.verdict}` + (v.value === null ? '' : ` (${v.value} ${v.unit}, bound ${v.bound})`))
    .join(' · ');
}

// The report's connections of the device, one block each: head, histogram, figures, verdicts.
export function drawConnections(box, device) {
  box.textContent = '';
  const connections = device ? device.connections : [];
  if (!connections.length) {
    box.appendChild(el('p', 'muted', 'no class-1 connection measured'));
    return;
  }
  for (const c of connections) {
    const block = el('div', 'measured verdict-' + c.verdict.replace(/ /g, '-'));
    block.dataset.oT = c.o_t_id;
    const id = '0x' + c.o_t_id.toString(16).toUpperCase().padStart(8, '0');
    block.appendChild(el('div', 'measured-head',
      `O->T ${id} from ${c.originator} · ${c.verdict}` + (c.ended ? ` · ended: ${c.ended}` : ' · open')));
    block.appendChild(histogram.draw(c.intervals));
    block.appendChild(el('div', 'muted figures', histogram.figures(c.intervals)));
    if (c.verdicts.length) block.appendChild(el('div', 'muted verdicts', verdictLine(c.verdicts)));
    box.appendChild(block);
  }
}

async function refresh() {
  if (!current) return;
  const name = current, seconds = Number($('#inspect-seconds').value);
  try {
    const answer = await api(`${devicePath(name)}/timeline?seconds=${seconds}`);
    if (current !== name) return;
    const box = $('#inspect-timeline');
    box.textContent = '';
    box.appendChild(timeline.draw(answer));
  } catch (error) {
    say(`${name}: timeline: ${error.message}`);
  }
  try {
    const report = await api(`report?device=${encodeURIComponent(name)}`);
    if (current !== name) return;
    drawConnections($('#inspect-connections'), report.devices.find(d => d.device === name));
  } catch (error) {
    $('#inspect-connections').textContent = `report: ${error.message}`;
  }
}

export function open(name) {
  current = name;
  $('#inspect-name').textContent = name;
  $('#inspect-timeline').textContent = '';
  $('#inspect-connections').textContent = '';
  if (!dialog().open) dialog().showModal();
  clearInterval(timer);
  timer = setInterval(refresh, REFRESH_MS);
  return refresh();
}

export function close() {
  current = null;
  clearInterval(timer);
  timer = null;
  if (dialog().open) dialog().close();
}

export function start() {
  $('#inspect-close').addEventListener('click', close);
  $('#inspect-seconds').addEventListener('change', refresh);
  dialog().onclose = () => { current = null; clearInterval(timer); timer = null; };  // Escape closes it too
}
