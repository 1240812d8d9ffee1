// A session's page: its map from above (topview.js) and in 3D (view3d.js), redrawn as
// captures arrive — the page listens to GET /v1/sessions/{id}/events and reads the map again
// (GET /v1/sessions/{id}/map) when the capture count changes — and a menu to download the map
// in every export format.
import { apiJson, download, el, listen, rigMarker, showError } from '/ui/common.js';
import { drawTopView, shade } from '/ui/topview.js';
import { View3d, webglAvailable } from '/ui/view3d.js';

const id = decodeURIComponent(location.pathname.split('/').filter(Boolean).pop());
const picked = document.getElementById('picked');
let view = null;
let current = { segments: [], poses: [], priors: [] };
let reading = null;
// Where the session rig's cameras are and where they look, in the rig frame.
let rig = { centre: [0, 0, 0], look: [0, 1, 0] };
let again = false;

const point = (p) => [p?.x ?? 0, p?.y ?? 0, p?.z ?? 0];

// A row-major 4x4 rig_to_world: where the rig's cameras are, and where they look on the floor.
function pose(matrix) {
  const m = matrix ?? [];
  const at = (v, w) => [0, 1, 2].map((i) => (m[4 * i] ?? 0) * v[0] + (m[4 * i + 1] ?? 0) * v[1] + (m[4 * i + 2] ?? 0) * v[2] + w * (m[4 * i + 3] ?? 0));
  const look = at(rig.look, 0);
  const n = Math.hypot(look[0], look[1]);
  return { at: at(rig.centre, 1), heading: n > 1e-6 ? [look[0] / n, look[1] / n] : null };
}

function describe(s, index) {
  return `map segment ${index}: seen by ${s.observations} capture${s.observations === 1 ? '' : 's'} (${(s.captures ?? []).join(', ')}), ` +
    `length ${s.length.toFixed(3)} m, direction σ ${Number(s.directionSigmaDeg ?? 0).toFixed(2)}°, ` +
    `position σ ${(1000 * Number(s.positionSigmaM ?? 0)).toFixed(1)} mm${s.uncertain ? ', uncertain' : ''}`;
}

function draw() {
  drawTopView(document.getElementById('top-view'), current.segments, current.poses, current.priors);
  if (!view) return;
  const most = Math.max(1, ...current.segments.map((s) => s.observations));
  view.show(
    current.segments.map((s) => ({ start: s.start, end: s.end, colour: shade(s.observations, Math.max(most, 2)).colour, data: s })),
    current.poses.map((p) => ({
      at: p.at,
      towards: p.heading ? [p.at[0] + 0.3 * p.heading[0], p.at[1] + 0.3 * p.heading[1], p.at[2]] : null,
      colour: '#1f5fd0',
    })),
  );
}

// Reads the map; a change announced while reading is read again after.
async function readMap() {
  if (reading) {
    again = true;
    return reading;
  }
  reading = (async () => {
    do {
      again = false;
      const map = await apiJson(`/v1/sessions/${id}/map`);
      current = {
        segments: (map.segments ?? []).map((s) => {
          const [start, end] = [point(s.start), point(s.end)];
          return {
            ...s,
            start,
            end,
            observations: s.observations ?? 0,
            length: Math.hypot(start[0] - end[0], start[1] - end[1], start[2] - end[2]),
          };
        }),
        poses: (map.poses ?? []).map((p) => pose(p.matrix)),
        priors: (map.priorPoses ?? []).map((p) => pose(p.matrix)),
      };
      document.getElementById('capture-count').textContent = String(current.poses.length);
      document.getElementById('segment-count').textContent = String(current.segments.length);
      document.getElementById('fuse-ms').textContent = Number(map.fuseMs ?? 0).toFixed(1);
      draw();
      document.body.dataset.mapCaptures = String(current.poses.length);
      document.body.dataset.drawnAt = String(performance.now());
    } while (again);
  })().finally(() => {
    reading = null;
  });
  return reading;
}

async function start() {
  try {
    const session = await apiJson(`/v1/sessions/${id}`);
    rig = rigMarker(session.calibration);
    document.getElementById('session-name').textContent = session.name || `Session ${id}`;
    document.title = `${session.name || id} · Trinocular`;
  } catch (error) {
    showError(document.querySelector('main section'), error);
    return;
  }
  if (webglAvailable()) {
    view = new View3d(document.getElementById('view-3d'), {
      up: [0, 0, 1],
      onPick: (s, index) => {
        picked.textContent = describe(s.data, index);
        current.segments.forEach((m) => (m.picked = m === s.data));
        drawTopView(document.getElementById('top-view'), current.segments, current.poses, current.priors);
      },
    });
  } else {
    document.getElementById('view-3d').replaceChildren(el('p', { class: 'muted' }, 'This browser has no WebGL: no 3D view.'));
  }
  await readMap().catch((error) => showError(picked, error));
  document.body.dataset.ready = 'true';
  const state = document.getElementById('live-state');
  const stop = new AbortController();
  listen(
    `/v1/sessions/${id}/events`,
    (name, data) => {
      if (name === 'gone') {
        state.textContent = 'the session is gone (deleted or expired)';
        return;
      }
      state.textContent = 'live';
      if (name === 'captures' && Number(data.captures) !== current.poses.length) {
        readMap().catch((error) => showError(picked, error));
      }
    },
    stop.signal,
  );
  window.addEventListener('resize', () => drawTopView(document.getElementById('top-view'), current.segments, current.poses, current.priors));
}

document.getElementById('download').addEventListener('change', async (event) => {
  const format = event.target.value;
  if (!format) return;
  try {
    await download(`/v1/sessions/${id}/map?format=${format}`, `map-${id}.${format}`);
  } catch (error) {
    showError(picked, error);
  }
  event.target.value = '';
});

start();
