// The page's DOM helpers: a query, an element maker, a sleep, and the message line (#message) that
// says what a request of the page answered.

export const $ = (selector, root = document) => root.querySelector(selector);

export const sleep = ms => new Promise(resolve => setTimeout(resolve, ms));

/** A count and its noun: `plural(1, 'device')` is `1 device`, `plural(2, 'device')` `2 devices`. */
export const plural = (count, noun) => `${count} ${count === 1 ? noun : noun + 's'}`;

export function el(tag, className, text) {
  const element = document.createElement(tag);
  if (className) element.className = className;
  if (text !== undefined) element.textContent = text;
  return element;
}

export function say(text, ok = false) {
  const line = $('#message');
  line.textContent = text;
  line.className = ok ? 'ok' : '';
}
