// SVG made in the page, no charting library: an element maker in the SVG namespace and a number
// with at most 3 decimals for attributes and titles.

const NS = 'http://www.w3.org/2000/svg';

export function svg(tag, attributes = {}, title) {
  const element = document.createElementNS(NS, tag);
  for (const [name, value] of Object.entries(attributes)) element.setAttribute(name, String(value));
  if (title !== undefined) {
    const tip = document.createElementNS(NS, 'title');
    tip.textContent = title;
    element.appendChild(tip);
  }
  return element;
}

export const fixed = value => Number(value.toFixed(3));
