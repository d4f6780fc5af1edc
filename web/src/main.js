// Entry point: start the client and publish window.daylit (status, and test hooks with ?test).
import { App } from './app.js';
import { debugApi } from './debug.js';

const params = new URLSearchParams(location.search);
const app = new App({
  canvas: document.getElementById('view'),
  hudRoot: document.getElementById('hud'),
  params,
});
const api = { status: app.status, version: 1 };
if (params.has('test')) api.debug = debugApi(app);
Object.defineProperty(window, 'daylit', { value: Object.freeze(api), writable: false });
app.start();
