// A connection's measured O->T packet intervals as a bar chart (the report's `intervals`: bucket
// counts by upper bound in multiples of the API, one more count for those above every bound), with
// the figures beside it: API, p50, p99, max, intervals of 2 API or more, the longest silence.

import { fixed, svg } from './svg.js';

export const WIDTH = 900, HEIGHT = 120, BOTTOM = 16;
// Bounds labelled under their bar (the others in the bar's title): the measurement's buckets are fine near 1 API.
export const LABELLED = new Set([0.5, 1, 1.5, 2, 4, 8, 16, 64]);

const ms = ns => (ns === null || ns === undefined ? '–' : `${fixed(ns / 1e6)} ms`);

// The bucket labels: "≤0.5", "≤1", ..., ">4" (bounds in API).
export function bucketLabels(bounds) {
  return [...bounds.map(bound => `\u2264${bound}`), `>${bounds[bounds.length - 1]}`];
}

// `intervals` (the report's) as an <svg> bar chart; a bar's height is its count against the
// largest, at least a pixel when it is not zero, so that one late interval among thousands shows.
export function draw(intervals) {
  const { counts, bounds_api: bounds } = intervals.histogram;
  const labels = bucketLabels(bounds), most = Math.max(1, ...counts), slot = WIDTH / counts.length;
  const root = svg('svg', { class: 'histogram', width: WIDTH, height: HEIGHT, viewBox: `0 0 ${WIDTH} ${HEIGHT}` });
  counts.forEach((count, i) => {
    const h = count ? Math.max(1, count / most * (HEIGHT - BOTTOM - 10)) : 0;
    root.appendChild(svg('rect', {
      class: 'bar' + (i >= counts.length - 1 || bounds[i] > 2 ? ' late' : ''), x: fixed(i * slot + 1),
      y: fixed(HEIGHT - BOTTOM - h), width: fixed(slot - 2), height: fixed(h), 'data-count': count,
    }, `${labels[i]} API: ${count}`));
    if (i < bounds.length && !LABELLED.has(bounds[i])) return;
    const label = svg('text', { x: fixed(i * slot + slot / 2), y: HEIGHT - 4, class: 'bucket' });
    label.textContent = labels[i];
    root.appendChild(label);
  });
  return root;
}

// One line of the figures under the chart.
export function figures(intervals) {
  return `API ${ms(intervals.api_ns)} · ${intervals.count} intervals · p50 ${ms(intervals.p50_ns)} · ` +
    `p99 ${ms(intervals.p99_ns)} · max ${ms(intervals.max_ns)} · \u22652 API: ${intervals.late} · ` +
    `longest silence ${ms(intervals.longest_silence_ns)}`;
}
