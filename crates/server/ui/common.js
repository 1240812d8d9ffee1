// What both pages share: the API called with the visitor's key (kept in this browser's
// localStorage, asked for when the service answers 401), a reader of the server-sent events
// of a session (over fetch, because EventSource cannot send the key), and a few DOM helpers.

const KEY_ITEM = 'trinocular.apiKey';

export function apiKey() {
  return localStorage.getItem(KEY_ITEM) || '';
}

export class ApiError extends Error {
  constructor(status, message, field) {
    super(field ? `${message} (${field})` : message);
    this.status = status;
    this.field = field;
  }
}

// fetch() on the service, with the key; an answer other than 2xx becomes an ApiError
// carrying the service's message and the field it names.
export async function api(path, init = {}) {
  const headers = new Headers(init.headers || {});
  const key = apiKey();
  if (key) headers.set('Authorization', `Bearer ${key}`);
  const response = await fetch(path, { ...init, headers });
  if (response.ok) return response;
  let message = `${response.status} ${response.statusText}`;
  let field;
  try {
    const body = await response.json();
    message = body.error?.message ?? message;
    field = body.error?.field;
  } catch {
    // Not the service's JSON error: keep the status line.
  }
  if (response.status === 401) askForKey(message);
  throw new ApiError(response.status, message, field);
}

export async function apiJson(path, init) {
  return (await api(path, init)).json();
}

// Calls onEvent(name, data) for each event of the stream at `path`, reconnecting after a
// dropped connection, until `signal` aborts or the session is gone.
export async function listen(path, onEvent, signal) {
  while (!signal.aborted) {
    try {
      const response = await api(path, { signal, headers: { Accept: 'text/event-stream' } });
      const reader = response.body.pipeThrough(new TextDecoderStream()).getReader();
      let buffer = '';
      for (;;) {
        const { value, done } = await reader.read();
        if (done) break;
        buffer += value;
        let end;
        while ((end = buffer.indexOf('\n\n')) >= 0) {
          const block = buffer.slice(0, end);
          buffer = buffer.slice(end + 2);
          let name = 'message';
          let data = '';
          for (const line of block.split('\n')) {
            if (line.startsWith('event:')) name = line.slice(6).trim();
            else if (line.startsWith('data:')) data += line.slice(5).trim();
          }
          if (data) onEvent(name, JSON.parse(data));
          if (name === 'gone') return;
        }
      }
    } catch (error) {
      if (signal.aborted) return;
      if (error.status === 404) {
        onEvent('gone', {});
        return;
      }
    }
    await new Promise((resolve) => setTimeout(resolve, 1000));
  }
}

// el('a', { href: '/x', class: 'y' }, 'text', child…)
export function el(tag, attributes = {}, ...children) {
  const node = document.createElement(tag);
  for (const [name, value] of Object.entries(attributes)) {
    if (value === undefined || value === null || value === false) continue;
    if (name.startsWith('on')) node.addEventListener(name.slice(2), value);
    else node.setAttribute(name, value === true ? '' : value);
  }
  node.append(...children.filter((c) => c !== undefined && c !== null));
  return node;
}

export function showError(where, error) {
  where.replaceChildren(el('p', { class: 'error', role: 'alert' }, String(error.message ?? error)));
}

// A colour per index, far apart for neighbours (golden-angle hues).
export function colour(i) {
  const hue = (i * 137.508) % 360;
  return `hsl(${hue.toFixed(1)}, 75%, 42%)`;
}

export function age(unixMs) {
  const s = Math.max(0, (Date.now() - Number(unixMs)) / 1000);
  if (s < 60) return `${Math.round(s)} s ago`;
  if (s < 3600) return `${Math.round(s / 60)} min ago`;
  if (s < 86400) return `${(s / 3600).toFixed(1)} h ago`;
  return `${(s / 86400).toFixed(1)} days ago`;
}

// A small form for the API key, shown when the service asks for one.
function askForKey(message) {
  if (document.getElementById('key-form')) return;
  const input = el('input', { type: 'password', id: 'key-input', placeholder: 'API key', autocomplete: 'off' });
  const form = el(
    'form',
    { id: 'key-form', class: 'key-form' },
    el('p', {}, `The service asks for an API key: ${message}`),
    input,
    el('button', { type: 'submit' }, 'Use this key'),
  );
  form.addEventListener('submit', (event) => {
    event.preventDefault();
    localStorage.setItem(KEY_ITEM, input.value.trim());
    location.reload();
  });
  document.body.prepend(form);
}

// Saves the answer of `path` as a file named `name`.
export async function download(path, name) {
  const blob = await (await api(path)).blob();
  const url = URL.createObjectURL(blob);
  const link = el('a', { href: url, download: name });
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}

// Each camera of a calibration (proto3 JSON) with its optical centre and unit optical axis in
// the rig frame: from P = [M | p4], C = -M^-1 p4 and the axis is M's third row (signed by
// det M); from K, R, t, C = -R^T t and the axis is R's third row. Cameras whose matrices do
// not give one are left out.
export function rigCameras(calibration) {
  const det = (a) => a[0] * (a[4] * a[8] - a[5] * a[7]) - a[1] * (a[3] * a[8] - a[5] * a[6]) + a[2] * (a[3] * a[7] - a[4] * a[6]);
  const unit = (v) => {
    const n = Math.hypot(...v);
    return n > 0 ? v.map((x) => x / n) : null;
  };
  return (calibration?.cameras ?? []).map((camera) => {
    const r = camera.rotation ?? [];
    const t = camera.translation ?? [];
    if (r.length === 9 && t.length === 3) {
      return {
        name: camera.name ?? '',
        centre: [0, 1, 2].map((j) => -(r[j] * t[0] + r[3 + j] * t[1] + r[6 + j] * t[2])),
        axis: unit([r[6], r[7], r[8]]),
      };
    }
    const p = camera.projection ?? [];
    if (p.length !== 12) return null;
    const m = [p[0], p[1], p[2], p[4], p[5], p[6], p[8], p[9], p[10]];
    const b = [-p[3], -p[7], -p[11]];
    const d = det(m);
    if (Math.abs(d) < 1e-12) return null;
    // Cramer's rule.
    const centre = [0, 1, 2].map((j) => {
      const mj = [...m];
      for (let i = 0; i < 3; i++) mj[3 * i + j] = b[i];
      return det(mj) / d;
    });
    return { name: camera.name ?? '', centre, axis: unit([m[6], m[7], m[8]].map((x) => Math.sign(d) * x)) };
  }).filter(Boolean);
}

// Where a rig's cameras are (their centroid) and where they look (their mean axis), in the
// rig frame — what the service's top views draw at each pose. Unknown: the origin, along +y.
export function rigMarker(calibration) {
  const cameras = rigCameras(calibration);
  if (cameras.length === 0) return { centre: [0, 0, 0], look: [0, 1, 0] };
  const mean = (k) => [0, 1, 2].map((i) => cameras.reduce((s, c) => s + (c[k]?.[i] ?? 0), 0) / cameras.length);
  return { centre: mean('centre'), look: mean('axis') };
}
