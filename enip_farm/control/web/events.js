// The farm's event stream (GET events, server-sent events) read with fetch, so that it carries
// the token: `parseEvents` splits the text into events, `follow` reads the stream for ever,
// reconnecting after RETRY_MS (5 s when the farm is busy, 503), and shows its state in #stream.

import { api } from './api.js';
import { $, say, sleep } from './dom.js';

const RETRY_MS = 1000, BUSY_MS = 5000;

// The whole events of `buffer` (each ends with a blank line) as {kind, data} (data parsed JSON;
// comments, the keep-alives, left out), and the text after the last whole one.
export function parseEvents(buffer) {
  const events = [];
  let end;
  while ((end = buffer.indexOf('\n\n')) >= 0) {
    const block = buffer.slice(0, end);
    buffer = buffer.slice(end + 2);
    let kind = 'message', data = '';
    for (const line of block.split('\n')) {
      if (line.startsWith('event: ')) kind = line.slice(7);
      else if (line.startsWith('data: ')) data += line.slice(6);
    }
    if (data) events.push({ kind, data: JSON.parse(data) });
  }
  return [events, buffer];
}

function badge(text, className = '') {
  const element = $('#stream');
  element.textContent = text;
  element.className = 'badge ' + className;
}

// Calls onLive() each time the stream is (again) live, onEvent(kind, data) for each event.
export async function follow(path, { onLive, onEvent }) {
  for (;;) {
    let retry = RETRY_MS;
    try {
      badge('connecting');
      const response = await api(path, { stream: true });
      badge('live', 'live');
      onLive();
      const reader = response.body.getReader();
      const decoder = new TextDecoder();
      let buffer = '';
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        let events;
        [events, buffer] = parseEvents(buffer + decoder.decode(value, { stream: true }));
        for (const event of events) onEvent(event.kind, event.data);
      }
      badge('ended', 'down');
    } catch (error) {
      badge(error.status === 503 ? 'busy' : 'down', 'down');
      if (error.status === 503) retry = BUSY_MS;
      if (error.status && error.status !== 503) say(`events: ${error.message}`);
    }
    await sleep(retry);
  }
}
