// A device's signal timeline as a logic analyser draws it (GET devices/{name}/timeline): one row
// a signal, digital ones as steps between low and high, analog ones as steps scaled to their range
// in the window; a vertical mark at each image change, coloured by who made it (`o->t` the
// controller's class-1 data, `explicit` its requests, `stimulus` the test's inputs, anything else a
// connection event such as a timeout), its title saying when, by whom and which signals; a running
// scenario's steps (`answer.steps`) as marks across every row, each titled with its line.

import { fixed, svg } from './svg.js';

export const WIDTH = 900, LABEL = 56, DIGITAL_H = 14, ANALOG_H = 34, GAP = 3, AXIS = 18;
export const MARK_CLASS = { 'o->t': 'by-o-t', explicit: 'by-explicit', stimulus: 'by-stimulus' };

const isDigital = signal => signal.type === 'DI' || signal.type === 'DO';

// The step path of `values` ([[t, v], ...], in order) from x(t) to the window's end, y(v) per value.
export function stepPath(values, x, y, end) {
  let d = '';
  values.forEach(([t, v], i) => {
    d += i ? ` H${fixed(x(t))} V${fixed(y(v))}` : `M${fixed(x(t))} ${fixed(y(v))}`;
  });
  return values.length ? d + ` H${fixed(x(end))}` : d;
}

// The timeline `answer` as an <svg> element; `only` (a Set of names) keeps those signals.
export function draw(answer, only = null) {
  const signals = answer.signals.filter(signal => !only || only.has(signal.name));
  const heights = signals.map(signal => (isDigital(signal) ? DIGITAL_H : ANALOG_H) + GAP);
  const height = heights.reduce((a, b) => a + b, 0) + AXIS;
  const span = Math.max(answer.now - answer.start, 1e-9), plot = WIDTH - LABEL - 4;
  const x = t => LABEL + (t - answer.start) / span * plot;
  const root = svg('svg', { class: 'timeline', width: WIDTH, height, viewBox: `0 0 ${WIDTH} ${height}` });
  let top = 0;
  signals.forEach((signal, i) => {
    const h = heights[i] - GAP, values = signal.values.map(([, v]) => v);
    const low = isDigital(signal) ? 0 : Math.min(...values), high = isDigital(signal) ? 1 : Math.max(...values);
    const y = v => top + h - (high === low ? 0.5 : (v - low) / (high - low)) * h;
    const row = svg('g', { class: `trace ${signal.role}`, 'data-signal': signal.name });
    row.appendChild(svg('text', { x: 2, y: top + h - 2, class: 'trace-label' })).textContent = signal.name;
    row.appendChild(svg('line', { x1: LABEL, x2: WIDTH - 4, y1: top + h + 1, y2: top + h + 1, class: 'baseline' }));
    const last = signal.values[signal.values.length - 1];
    row.appendChild(svg('path', { d: stepPath(signal.values, x, y, answer.now), class: 'step' },
                        `${signal.name}: ${last ? last[1] : ''}` + (isDigital(signal) ? '' : ` (${low} to ${high})`)));
    root.appendChild(row);
    top += heights[i];
  });
  for (const mark of answer.marks) {
    if (only && !mark.signals.some(name => only.has(name))) continue;
    const at = fixed(x(mark.at));
    root.appendChild(svg('line', {
      class: `mark ${MARK_CLASS[mark.by] || 'by-event'}`, x1: at, x2: at, y1: 0, y2: top,
      'data-by': mark.by, 'data-signals': mark.signals.join(','),
    }, `${(mark.at - answer.now).toFixed(3)} s: ${mark.by} ${mark.signals.join(', ')}`));
  }
  for (const step of answer.steps || []) {
    const at = fixed(x(step.at));
    root.appendChild(svg('line', {
      class: 'mark by-scenario', x1: at, x2: at, y1: 0, y2: top, 'data-by': 'scenario step', 'data-step': step.text,
    }, `${(step.at - answer.now).toFixed(3)} s: ${step.text}`));
  }
  const axis = svg('text', { x: LABEL, y: height - 4, class: 'axis' });
  axis.textContent = `${fixed(span)} s to now`;
  root.appendChild(axis);
  return root;
}
