"use strict";
// A packing drawn on a 2D canvas: the one drawing of the handout (engine/io/export/html.py) and of the
// viewers' scene (static/viewer/scene.html, served by app/lab/server.py). Each page says what to draw
// in a picture `p`, in world coordinates (y up):
//   width, height: the canvas's size in CSS pixels (the context is already scaled to the device's)
//   bounds [x0, x1, y0, y1]: what must show, fitted with a margin; meanRadius: the unit of line widths
//   n disks: x(i), y(i), radius(i), angle(i) (radians), fill(i) (a colour); edge: their outline's colour
//   forces: false to leave out the force network, else {count, segment(c) -> [x0, y0, x1, y1],
//     level(c) in 0..levels-1 (line width), kind(c) (colour in kindColors), levels, width (of the widest,
//     in mean radii), kindColors}
//   watched: [[x0, y0, x1, y1, colour], ...] and watchedWidth (mean radii); spoke, wall, cell colours;
//   walls: [x0, y0, x1, y1, ...] (NaN: a wall left out); cell: [lx, ly] or null (dashed, from the origin);
//   arrows: [x0, y0, x1, y1, ...] drawn over everything in arrowColor, arrowWidth (mean radii);
//   labels: [[text, x, y], ...], kept inside the picture.
function drawPacking(ctx, p) {
  ctx.fillStyle = "#ffffff";
  ctx.fillRect(0, 0, p.width, p.height);
  const [x0, x1, y0, y1] = p.bounds, pad = 10, w = p.width, h = p.height;
  if (w <= 2 * pad || h <= 2 * pad) return;
  const s = Math.min((w - 2 * pad) / Math.max(x1 - x0, 1e-12), (h - 2 * pad) / Math.max(y1 - y0, 1e-12));
  const ox = w / 2 - s * (x0 + x1) / 2, oy = h / 2 + s * (y0 + y1) / 2;
  const X = x => ox + s * x, Y = y => oy - s * y, unit = p.meanRadius * s;
  const line = (x0, y0, x1, y1) => { ctx.moveTo(X(x0), Y(y0)); ctx.lineTo(X(x1), Y(y1)); };
  ctx.lineWidth = Math.max(0.3, 0.04 * unit);
  ctx.strokeStyle = p.edge;
  for (let i = 0; i < p.n; i++) {
    ctx.beginPath();
    ctx.arc(X(p.x(i)), Y(p.y(i)), p.radius(i) * s, 0, 2 * Math.PI);
    ctx.fillStyle = p.fill(i);
    ctx.fill();
    ctx.stroke();
  }
  const f = p.forces;
  if (f) {
    const widths = Array.from({length: f.levels}, (_, q) => Math.max(1, (q + 1) / f.levels * f.width * unit));
    const segment = c => line(...f.segment(c));
    ctx.lineCap = "butt";
    // a white border under every line first: red on a red disk would not show, and no border may cut a line
    ctx.strokeStyle = "#ffffff";
    for (let q = 0; q < f.levels; q++) {
      ctx.lineWidth = widths[q] * 1.24;
      ctx.beginPath();
      for (let c = 0; c < f.count; c++) if (f.level(c) === q) segment(c);
      ctx.stroke();
    }
    for (let q = 0; q < f.levels; q++) {  // the strongest last, on top
      for (let kind = 0; kind < f.kindColors.length; kind++) {
        ctx.strokeStyle = f.kindColors[kind];
        ctx.lineWidth = widths[q];
        ctx.beginPath();
        for (let c = 0; c < f.count; c++) if (f.level(c) === q && f.kind(c) === kind) segment(c);
        ctx.stroke();
      }
    }
  }
  const watchedWidth = Math.max(2, p.watchedWidth * unit);
  for (const [ax, ay, bx, by, color] of p.watched) {
    for (const [paint, width] of [["#ffffff", watchedWidth + 2], [color, watchedWidth]]) {
      ctx.strokeStyle = paint;
      ctx.lineWidth = width;
      ctx.beginPath();
      line(ax, ay, bx, by);
      ctx.stroke();
    }
  }
  ctx.strokeStyle = p.spoke;
  ctx.lineWidth = Math.max(1, 0.12 * unit);
  ctx.beginPath();
  for (let i = 0; i < p.n; i++) {
    const x = p.x(i), y = p.y(i), r = p.radius(i), a = p.angle(i);
    line(x, y, x + r * Math.cos(a), y + r * Math.sin(a));
  }
  ctx.stroke();
  ctx.strokeStyle = p.wall;
  ctx.lineWidth = Math.max(2, 0.25 * unit);
  ctx.lineCap = "square";
  ctx.beginPath();
  for (let e = 0; e + 3 < p.walls.length; e += 4) {
    if (!isNaN(p.walls[e])) line(p.walls[e], p.walls[e + 1], p.walls[e + 2], p.walls[e + 3]);
  }
  ctx.stroke();
  ctx.lineCap = "butt";
  if (p.cell) {
    ctx.strokeStyle = p.cellColor;
    ctx.lineWidth = Math.max(1.5, 0.12 * unit);
    ctx.setLineDash([6, 4]);
    ctx.strokeRect(X(0), Y(p.cell[1]), p.cell[0] * s, p.cell[1] * s);
    ctx.setLineDash([]);
  }
  if (p.arrows.length) {  // over everything, as in the 3D scene
    const arrowWidth = Math.max(2, p.arrowWidth * unit);
    ctx.lineCap = "round";
    for (const [paint, width] of [["#ffffff", arrowWidth + 2], [p.arrowColor, arrowWidth]]) {
      ctx.strokeStyle = paint;
      ctx.lineWidth = width;
      ctx.beginPath();
      const A = p.arrows;
      for (let e = 0; e + 3 < A.length; e += 4) line(A[e], A[e + 1], A[e + 2], A[e + 3]);
      ctx.stroke();
    }
    ctx.lineCap = "butt";
  }
  ctx.fillStyle = "#1a1a1a";
  ctx.font = `${Math.max(14, 0.45 * unit)}px sans-serif`;
  ctx.textAlign = "center";
  ctx.textBaseline = "top";
  for (const [text, x, y] of p.labels) {  // a name wider than its disks stays inside the picture
    const half = ctx.measureText(text).width / 2;
    ctx.fillText(text, Math.min(Math.max(X(x), half + 2), w - half - 2), Y(y));
  }
}

// The canvas sized to its box (w × h CSS pixels) at the device's pixel ratio, its context scaled to match.
function fitCanvas(canvas, ctx, w, h) {
  const dpr = window.devicePixelRatio || 1;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
  }
  ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
}
