// The first page: the caller's sessions, and a Match page — three images and a calibration
// (or the sample triplet) sent to POST /v1/match as a multipart upload, answered with the
// extracted segments drawn over the images (matched ones coloured by their 3D segment,
// the others grey) and the 3D segments in a view to turn.
import { apiJson, age, colour, el, rigCameras, showError } from '/ui/common.js';
import { View3d, webglAvailable } from '/ui/view3d.js';

async function loadSessions() {
  const where = document.getElementById('sessions');
  try {
    const { sessions = [] } = await apiJson('/v1/sessions?page_size=1000');
    if (sessions.length === 0) {
      where.replaceChildren(
        el('p', { class: 'muted', id: 'no-sessions' }, 'No sessions yet. A robot creates one with POST /v1/sessions (see the README).'),
      );
      return;
    }
    sessions.sort((a, b) => Number(b.lastUsedUnixMs) - Number(a.lastUsedUnixMs));
    const rows = sessions.map((s) =>
      el(
        'tr',
        { class: 'session-row' },
        el('td', {}, el('a', { href: `/sessions/${s.id}` }, s.name || '(no name)')),
        el('td', { class: 'number' }, String(s.captures ?? 0)),
        el('td', {}, age(s.createdUnixMs)),
        el('td', {}, age(s.lastUsedUnixMs)),
        el('td', { class: 'muted' }, s.id),
      ),
    );
    where.replaceChildren(
      el(
        'table',
        { id: 'sessions-table' },
        el('thead', {}, el('tr', {}, ...['name', 'captures', 'created', 'last used', 'id'].map((h) => el('th', { class: h === 'captures' ? 'number' : undefined }, h)))),
        el('tbody', {}, ...rows),
      ),
    );
  } catch (error) {
    showError(where, error);
  }
}

// The sample triplet's files, as the form would send them.
async function sampleFiles() {
  const get = async (name, type) => new File([await (await fetch(`/ui/sample/${name}`)).blob()], name, { type });
  return {
    image1: await get('image1.png', 'image/png'),
    image2: await get('image2.png', 'image/png'),
    image3: await get('image3.png', 'image/png'),
    calibration: await get('calibration.json', 'application/json'),
  };
}

function formFiles(form) {
  const files = {};
  for (const name of ['image1', 'image2', 'image3', 'calibration']) {
    const file = form.elements[name].files[0];
    if (!file) throw new Error(`choose a file for ${name}, or use the sample triplet`);
    files[name] = file;
  }
  return files;
}

async function match(files, includeUncertain) {
  const status = document.getElementById('match-status');
  const result = document.getElementById('match-result');
  status.textContent = 'matching…';
  const body = new FormData();
  body.append('calibration', files.calibration);
  body.append('options', new Blob([JSON.stringify({ returnExtracted: true, includeUncertain })], { type: 'application/json' }));
  for (const name of ['image1', 'image2', 'image3']) body.append(name, files[name]);
  try {
    const response = await apiJson('/v1/match', { method: 'POST', body });
    status.textContent = '';
    await showMatch(result, files, response);
  } catch (error) {
    status.textContent = '';
    showError(result, error);
  }
}

async function showMatch(where, files, response) {
  const segments3d = response.segments3d ?? [];
  const triplets = response.triplets ?? [];
  const extracted = response.extracted ?? [];
  const stats = response.stats ?? {};
  // Which 3D segment each image segment went into, per view.
  const owner = [new Map(), new Map(), new Map()];
  segments3d.forEach((s, k) => {
    const ids = s.triplets?.length ? s.triplets : [s.triplet ?? 0];
    for (const t of ids) {
      const triplet = triplets[t];
      if (!triplet) continue;
      [triplet.s1 ?? 0, triplet.s2 ?? 0, triplet.s3 ?? 0].forEach((i, v) => owner[v].set(i, k));
    }
  });
  const names = await cameraNames(files.calibration);
  const figures = [];
  for (let v = 0; v < 3; v++) {
    const canvas = el('canvas', { id: `overlay-${v + 1}`, class: 'overlay' });
    const list = extracted[v]?.segments ?? [];
    const matched = list.filter((_, i) => owner[v].has(i)).length;
    figures.push(el('figure', {}, canvas, el('figcaption', {}, `camera ${v + 1}${names[v] ? ` (${names[v]})` : ''}: ${list.length} segments, ${matched} matched`)));
    await drawOverlay(canvas, files[`image${v + 1}`], list, owner[v]);
  }
  const facts = el(
    'p',
    { id: 'match-facts' },
    `${segments3d.length} 3D segments from ${triplets.length} triplets in ${Number(stats.totalMs ?? 0).toFixed(1)} ms`,
    stats.uncertain ? ` (${stats.uncertain} more left out as uncertain)` : '',
    stats.collinearRig ? ' — the rig is collinear: matched with two cameras' : '',
  );
  const legend = el(
    'div',
    { class: 'legend' },
    el('span', { style: `--swatch: ${colour(0)}` }, 'matched: one colour per 3D segment'),
    el('span', { style: '--swatch: #9a9a9a' }, 'extracted, not matched'),
    el('span', { style: '--swatch: #000' }, 'dot: segment start (contrast on its right)'),
  );
  const three = el('div', { class: 'three', id: 'match-3d' });
  const picked = el('p', { class: 'picked', id: 'match-picked' }, 'Click a 3D segment to see its uncertainty. Rig frame, metres.');
  where.replaceChildren(facts, legend, el('div', { class: 'views' }, ...figures), three, picked);
  if (!webglAvailable()) {
    three.replaceChildren(el('p', { class: 'muted' }, 'This browser has no WebGL: no 3D view.'));
    return;
  }
  const view = new View3d(three, {
    up: [0, 0, 1],
    onPick: (s) => {
      picked.textContent = `3D segment ${s.data.index}: length ${s.data.length.toFixed(3)} m, direction σ ${Number(s.data.directionSigmaDeg ?? 0).toFixed(2)}°, position σ ${(1000 * Number(s.data.positionSigmaM ?? 0)).toFixed(1)} mm, residual ${Number(s.data.residualPx ?? 0).toFixed(2)} px${s.data.uncertain ? ', uncertain' : ''}`;
    },
  });
  const point = (p) => [p?.x ?? 0, p?.y ?? 0, p?.z ?? 0];
  view.show(
    segments3d.map((s, index) => {
      const [a, b] = [point(s.start), point(s.end)];
      return { start: a, end: b, colour: colour(index), data: { ...s, index, length: Math.hypot(a[0] - b[0], a[1] - b[1], a[2] - b[2]) } };
    }),
    (await cameraCentres(files.calibration)).map((c) => ({ at: c, towards: null, colour: '#1f5fd0' })),
  );
}

async function cameraNames(file) {
  try {
    return (JSON.parse(await file.text()).cameras ?? []).map((c) => c.name ?? '');
  } catch {
    return [];
  }
}

// The cameras' optical centres in the rig frame, to draw the rig where its cameras are.
async function cameraCentres(file) {
  try {
    return rigCameras(JSON.parse(await file.text())).map((c) => c.centre);
  } catch {
    return [];
  }
}

async function drawOverlay(canvas, file, list, owner) {
  let bitmap = null;
  try {
    bitmap = await createImageBitmap(file);
  } catch {
    // A format the browser cannot show (PGM): the segments on grey.
  }
  const xs = list.flatMap((s) => [s.u1 ?? 0, s.u2 ?? 0]);
  const ys = list.flatMap((s) => [s.v1 ?? 0, s.v2 ?? 0]);
  canvas.width = bitmap?.width ?? Math.ceil(Math.max(64, ...xs));
  canvas.height = bitmap?.height ?? Math.ceil(Math.max(64, ...ys));
  const g = canvas.getContext('2d');
  g.fillStyle = '#444';
  g.fillRect(0, 0, canvas.width, canvas.height);
  if (bitmap) {
    g.globalAlpha = 0.55;
    g.drawImage(bitmap, 0, 0);
    g.globalAlpha = 1;
  }
  // Pixel centres at integer coordinates (the conventions): +0.5 to the canvas's.
  const line = (s, style, width) => {
    g.strokeStyle = style;
    g.lineWidth = width;
    g.beginPath();
    g.moveTo((s.u1 ?? 0) + 0.5, (s.v1 ?? 0) + 0.5);
    g.lineTo((s.u2 ?? 0) + 0.5, (s.v2 ?? 0) + 0.5);
    g.stroke();
  };
  const thick = Math.max(1.5, canvas.width / 400);
  list.forEach((s, i) => owner.has(i) || line(s, '#9a9a9a', thick * 0.7));
  list.forEach((s, i) => {
    if (!owner.has(i)) return;
    const c = colour(owner.get(i));
    line(s, c, thick);
    g.fillStyle = c;
    g.fillRect((s.u1 ?? 0) + 0.5 - thick, (s.v1 ?? 0) + 0.5 - thick, 2 * thick, 2 * thick);
  });
}

document.getElementById('match-form').addEventListener('submit', async (event) => {
  event.preventDefault();
  const form = event.target;
  try {
    await match(formFiles(form), form.elements.uncertain.checked);
  } catch (error) {
    showError(document.getElementById('match-result'), error);
  }
});
document.getElementById('sample-button').addEventListener('click', async () => {
  const form = document.getElementById('match-form');
  await match(await sampleFiles(), form.elements.uncertain.checked);
});
loadSessions();
