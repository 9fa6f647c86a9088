// One animation frame for all DOM work of the page, however many reads and events came since the
// last: modules register what they do in a frame (`onFrame`, run in registration order) and ask
// for the next frame (`schedule`), at most one pending.

const tasks = [];
let scheduled = false;

export function onFrame(task) {
  tasks.push(task);
}

export function schedule() {
  if (!scheduled) {
    scheduled = true;
    requestAnimationFrame(frame);
  }
}

function frame() {
  scheduled = false;
  for (const task of tasks) task();
}
