// A session's map from above, as a floor plan (world x right, y up): a metre grid with
// labelled ticks, a scale bar, the axes, the segments darker and thicker the more captures
// saw them, each rig pose where its cameras were with its heading (and, in orange, where
// the robot said it was), and a legend. Drawn on a canvas, cropped to the content.

const POSE = '#1f5fd0';
const PRIOR = '#e67814';

// Grey level and width of a segment seen `n` times out of `most`.
export function shade(n, most) {
  const f = most > 1 ? (n - 1) / (most - 1) : 1;
  const g = Math.round(170 * (1 - f));
  return { colour: `rgb(${g},${g},${g})`, width: 1 + 2 * f };
}

// poses: [{ at: [x, y, z], heading: [dx, dy] or null }]; priors likewise (or empty).
export function drawTopView(canvas, segments, poses, priors) {
  const ratio = window.devicePixelRatio || 1;
  const width = canvas.clientWidth;
  const height = canvas.clientHeight;
  canvas.width = Math.round(width * ratio);
  canvas.height = Math.round(height * ratio);
  const g = canvas.getContext('2d');
  g.setTransform(ratio, 0, 0, ratio, 0, 0);
  g.fillStyle = '#ffffff';
  g.fillRect(0, 0, width, height);

  const xs = [];
  const ys = [];
  for (const s of segments) xs.push(s.start[0], s.end[0]), ys.push(s.start[1], s.end[1]);
  for (const p of [...poses, ...priors]) xs.push(p.at[0]), ys.push(p.at[1]);
  let [xmin, xmax, ymin, ymax] = xs.length
    ? [Math.min(...xs), Math.max(...xs), Math.min(...ys), Math.max(...ys)]
    : [-1, 1, -1, 1];
  const margin = { left: 48, right: 16, top: 16, bottom: 64 };
  const span = Math.max(xmax - xmin, ymax - ymin, 0.5);
  const scale = Math.min(
    (width - margin.left - margin.right) / Math.max(xmax - xmin, span * 0.2),
    (height - margin.top - margin.bottom) / Math.max(ymax - ymin, span * 0.2),
  );
  const cx = (xmin + xmax) / 2;
  const cy = (ymin + ymax) / 2;
  const ox = margin.left + (width - margin.left - margin.right) / 2;
  const oy = margin.top + (height - margin.top - margin.bottom) / 2;
  const px = (x, y) => [ox + (x - cx) * scale, oy - (y - cy) * scale];

  // Metre grid (every metre, or every 0.5/2/5 m to keep 40+ px between lines).
  const step = [0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50].find((s) => s * scale >= 40) ?? 100;
  const [x0, x1] = [cx - (ox - margin.left) / scale, cx + (width - margin.right - ox) / scale];
  const [y0, y1] = [cy - (height - margin.bottom - oy) / scale, cy + (oy - margin.top) / scale];
  g.font = '11px sans-serif';
  g.lineWidth = 1;
  for (let x = Math.ceil(x0 / step) * step; x <= x1; x += step) {
    const [u] = px(x, 0);
    g.strokeStyle = Math.abs(x) < 1e-9 ? '#b0b0b0' : '#e6e6e6';
    g.beginPath();
    g.moveTo(u, margin.top);
    g.lineTo(u, height - margin.bottom);
    g.stroke();
    g.fillStyle = '#555';
    g.textAlign = 'center';
    g.fillText(`${+x.toFixed(2)}`, u, height - margin.bottom + 14);
  }
  for (let y = Math.ceil(y0 / step) * step; y <= y1; y += step) {
    const [, v] = px(0, y);
    g.strokeStyle = Math.abs(y) < 1e-9 ? '#b0b0b0' : '#e6e6e6';
    g.beginPath();
    g.moveTo(margin.left, v);
    g.lineTo(width - margin.right, v);
    g.stroke();
    g.fillStyle = '#555';
    g.textAlign = 'right';
    g.fillText(`${+y.toFixed(2)}`, margin.left - 6, v + 4);
  }
  g.textAlign = 'left';
  g.fillText('x (m) →', width - margin.right - 50, height - margin.bottom + 28);
  g.save();
  g.translate(12, margin.top + 40);
  g.rotate(-Math.PI / 2);
  g.fillText('y (m) →', 0, 0);
  g.restore();

  const most = Math.max(1, ...segments.map((s) => s.observations));
  const order = [...segments].sort((a, b) => a.observations - b.observations);
  g.lineCap = 'round';
  for (const s of order) {
    const { colour, width: w } = shade(s.observations, most);
    g.strokeStyle = s.picked ? '#ff2d55' : colour;
    g.lineWidth = s.picked ? 3 : w;
    g.beginPath();
    g.moveTo(...px(s.start[0], s.start[1]));
    g.lineTo(...px(s.end[0], s.end[1]));
    g.stroke();
  }
  const marker = (p, colour, filled) => {
    const [u, v] = px(p.at[0], p.at[1]);
    g.strokeStyle = colour;
    g.fillStyle = colour;
    g.lineWidth = 2;
    g.beginPath();
    g.arc(u, v, 4, 0, 2 * Math.PI);
    if (filled) g.fill();
    else g.stroke();
    if (p.heading) {
      g.beginPath();
      g.moveTo(u, v);
      g.lineTo(u + 16 * p.heading[0], v - 16 * p.heading[1]);
      g.stroke();
    }
    return [u, v];
  };
  priors.forEach((prior, i) => {
    const [u, v] = marker(prior, PRIOR, false);
    if (poses[i]) {
      g.setLineDash([2, 2]);
      g.lineWidth = 1;
      g.beginPath();
      g.moveTo(u, v);
      g.lineTo(...px(poses[i].at[0], poses[i].at[1]));
      g.stroke();
      g.setLineDash([]);
    }
  });
  for (const p of poses) marker(p, POSE, true);

  // Scale bar, bottom left, and the legend beside it.
  const bar = [0.1, 0.2, 0.5, 1, 2, 5, 10, 20, 50].filter((l) => l * scale <= width / 4).pop() ?? 0.1;
  const by = height - 18;
  g.strokeStyle = '#000';
  g.fillStyle = '#000';
  g.lineWidth = 2;
  g.beginPath();
  g.moveTo(margin.left, by - 5);
  g.lineTo(margin.left, by);
  g.lineTo(margin.left + bar * scale, by);
  g.lineTo(margin.left + bar * scale, by - 5);
  g.stroke();
  g.textAlign = 'left';
  g.fillText(`${bar} m`, margin.left + bar * scale + 6, by + 4);
  let lx = margin.left + bar * scale + 56;
  const item = (draw, text) => {
    draw(lx, by);
    g.fillStyle = '#222';
    g.fillText(text, lx + 22, by + 4);
    lx += 30 + g.measureText(text).width;
  };
  item((x, y) => {
    g.fillStyle = POSE;
    g.beginPath();
    g.arc(x + 8, y, 4, 0, 2 * Math.PI);
    g.fill();
  }, 'rig pose (map)');
  if (priors.length) {
    item((x, y) => {
      g.strokeStyle = PRIOR;
      g.lineWidth = 2;
      g.beginPath();
      g.arc(x + 8, y, 4, 0, 2 * Math.PI);
      g.stroke();
    }, 'pose as given');
  }
  const lineSwatch = (a) => (x, y) => {
    g.strokeStyle = a.colour;
    g.lineWidth = a.width;
    g.beginPath();
    g.moveTo(x, y);
    g.lineTo(x + 16, y);
    g.stroke();
  };
  item(lineSwatch(shade(1, Math.max(most, 2))), 'seen once');
  if (most > 1) item(lineSwatch(shade(most, most)), `seen ${most} times`);
  // North (world +y), top right.
  const nx = width - margin.right - 14;
  const ny = margin.top + 26;
  g.fillStyle = '#222';
  g.beginPath();
  g.moveTo(nx, ny - 18);
  g.lineTo(nx - 6, ny);
  g.lineTo(nx + 6, ny);
  g.closePath();
  g.fill();
  g.textAlign = 'center';
  g.fillText('+y', nx, ny + 14);
  return { scale, px };
}
