// The report's match replay: decodes a scene of logiq_sql/replay.py (gzip + base64 JSON in a <script> tag, read
// only when the match is opened) and draws it on a canvas with the layout and colours that replay.py's matplotlib
// renderer uses (LAYOUT, STYLE, SERIES, PANELS in the replay-config tag).
(function () {
  'use strict';
  const CONFIG = JSON.parse(document.getElementById('replay-config').textContent);
  const L = CONFIG.layout, S = CONFIG.style;
  const dialog = document.getElementById('replay');
  const canvas = document.getElementById('replay-canvas');
  const ctx = canvas.getContext('2d');
  const slider = document.getElementById('replay-slider');
  const label = document.getElementById('replay-frame');
  const title = document.getElementById('replay-title');
  const playButton = document.getElementById('replay-play');
  const maps = {};
  let scene = null, frame = 0, timer = null, token = 0, shown = null;

  async function unpack(id) {
    const text = document.getElementById(id).textContent.trim();
    const bytes = Uint8Array.from(atob(text), (c) => c.charCodeAt(0));
    const stream = new Blob([bytes]).stream().pipeThrough(new DecompressionStream('gzip'));
    return JSON.parse(await new Response(stream).text());
  }

  function undelta(values, scale, offset) {
    const out = new Array(values.length);
    let last = 0;
    for (let i = 0; i < values.length; i++) {
      if (values[i] === null) { out[i] = null; continue; }
      last += values[i];
      out[i] = last * scale + offset;
    }
    return out;
  }

  function actor(a, q, origin, n, index) {
    const x = undelta(a.x, q, origin[0]), y = undelta(a.y, q, origin[1]), h = undelta(a.h, 0.01, 0);
    if (!index) return { x: x, y: y, h: h, l: (a.l || 0) * q, w: (a.w || 0) * q };
    // an other road user: its values are given at frame indexes only
    const at = undelta(index, 1, 0), X = new Array(n).fill(null), Y = X.slice(), H = X.slice();
    at.forEach((i, k) => { X[i] = x[k]; Y[i] = y[k]; H[i] = h[k]; });
    return { x: X, y: Y, h: H, l: a.l * q, w: a.w * q };
  }

  function rings(part, q) {
    if (!part) return [];
    return part.map((ring) => {
      const pts = [];
      let x = 0, y = 0;
      for (let k = 0; k < ring.length; k += 2) {
        x += ring[k]; y += ring[k + 1];
        pts.push([x * q, y * q]);
      }
      return pts;
    });
  }

  function decode(s, map) {
    const n = s.f.length, frames = undelta(s.f, 1, 0), q = s.q;
    const scale = {};
    CONFIG.series.forEach((c) => { scale[c[0]] = c[2]; });
    const series = {};
    Object.keys(s.s).forEach((c) => { series[c] = s.s[c].map((v) => (v === null ? null : v * scale[c])); });
    const shift = map ? [map.origin[0], map.origin[1]] : [0, 0];
    const moved = (list) => list.map((r) => r.map((p) => [p[0] + shift[0], p[1] + shift[1]]));
    return {
      meta: s, n: n, t: frames.map((f) => s.t0 + (f - frames[0]) * s.dt),
      ego: actor(s.e, q, s.origin), actor: actor(s.a, q, s.origin),
      others: s.o.map((o) => Object.assign(actor(o, q, s.origin, n, o.i), { kind: o.k })),
      series: series, phases: s.p,
      lanes: map ? moved(rings(map.lanes, map.q)) : [], junctions: map ? moved(rings(map.junctions, map.q)) : [],
    };
  }

  function rect(part) {
    return [part[0] * canvas.width, part[1] * canvas.height, part[2] * canvas.width, part[3] * canvas.height];
  }

  function box(toPx, x, y, h, l, w, fill, alpha) {
    const c = Math.cos(h), s = Math.sin(h);
    const corners = [[1, 1], [1, -1], [-1, -1], [-1, 1]].map((p) => toPx(
      x + p[0] * l / 2 * c - p[1] * w / 2 * s, y + p[0] * l / 2 * s + p[1] * w / 2 * c));
    ctx.globalAlpha = alpha;
    ctx.fillStyle = fill;
    ctx.strokeStyle = '#000';
    ctx.lineWidth = 1;
    ctx.beginPath();
    corners.forEach((p, k) => (k ? ctx.lineTo(p[0], p[1]) : ctx.moveTo(p[0], p[1])));
    ctx.closePath();
    ctx.fill();
    ctx.stroke();
    // the heading: a line from the centre to the middle of the front edge
    const centre = toPx(x, y), nose = toPx(x + l / 2 * c, y + l / 2 * s);
    ctx.strokeStyle = '#fff';
    ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(centre[0], centre[1]); ctx.lineTo(nose[0], nose[1]); ctx.stroke();
    ctx.globalAlpha = 1;
    return centre;
  }

  function polygon(toPx, pts, fill, edge, alpha) {
    ctx.globalAlpha = alpha;
    ctx.beginPath();
    pts.forEach((p, k) => { const q = toPx(p[0], p[1]); if (k) ctx.lineTo(q[0], q[1]); else ctx.moveTo(q[0], q[1]); });
    ctx.closePath();
    ctx.fillStyle = fill; ctx.fill();
    ctx.strokeStyle = edge; ctx.lineWidth = 1; ctx.stroke();
    ctx.globalAlpha = 1;
  }

  function path(toPx, xs, ys, upto, colour) {
    ctx.strokeStyle = colour; ctx.globalAlpha = 0.5; ctx.lineWidth = 2;
    ctx.beginPath();
    let open = false;
    for (let i = 0; i <= upto; i++) {
      if (xs[i] === null) { open = false; continue; }
      const p = toPx(xs[i], ys[i]);
      if (open) ctx.lineTo(p[0], p[1]); else ctx.moveTo(p[0], p[1]);
      open = true;
    }
    ctx.stroke(); ctx.globalAlpha = 1;
  }

  function drawMap(d, i) {
    const [x0, y0, w, h] = rect(L.map);
    const k = w / (2 * d.meta.view_m), cx = d.ego.x[i], cy = d.ego.y[i];
    const toPx = (x, y) => [x0 + w / 2 + (x - cx) * k, y0 + h / 2 - (y - cy) * k];
    ctx.save();
    ctx.beginPath(); ctx.rect(x0, y0, w, h); ctx.clip();
    ctx.fillStyle = S.background; ctx.fillRect(x0, y0, w, h);
    d.lanes.forEach((r) => polygon(toPx, r, S.lane_fill, S.lane_edge, 1));
    d.junctions.forEach((r) => polygon(toPx, r, S.junction_fill, S.junction_edge, S.junction_alpha));
    d.others.forEach((o) => { if (o.x[i] !== null) box(toPx, o.x[i], o.y[i], o.h[i], o.l, o.w, S.other, S.other_alpha); });
    path(toPx, d.actor.x, d.actor.y, i, S.actor);
    path(toPx, d.ego.x, d.ego.y, i, S.ego);
    const state = { ego: box(toPx, cx, cy, d.ego.h[i], d.ego.l, d.ego.w, S.ego, 1), actor: null };
    if (d.actor.x[i] !== null) {
      state.actor = box(toPx, d.actor.x[i], d.actor.y[i], d.actor.h[i], d.actor.l, d.actor.w, S.actor, 1);
    }
    // a 10 m scale bar in the lower left corner
    ctx.fillStyle = '#333'; ctx.fillRect(x0 + 10, y0 + h - 14, 10 * k, 3);
    ctx.font = '11px system-ui, sans-serif'; ctx.fillText('10 m', x0 + 14 + 10 * k, y0 + h - 10);
    ctx.restore();
    ctx.strokeStyle = '#999'; ctx.strokeRect(x0, y0, w, h);
    return state;
  }

  function drawTimeline(d, i) {
    const [x0, y0, w, h] = rect(L.timeline);
    const at = (j) => x0 + (d.n > 1 ? j / (d.n - 1) : 0) * w;
    ctx.fillStyle = '#eee'; ctx.fillRect(x0, y0 + 4, w, h - 8);
    ctx.font = '11px system-ui, sans-serif';
    d.phases.forEach((p) => {
      const a = p[2] === null ? 0 : p[2], b = p[3] === null ? d.n - 1 : p[3];
      ctx.fillStyle = S.phases[(p[0] - 1) % S.phases.length];
      ctx.fillRect(at(a), y0 + 4, Math.max(at(b) - at(a), 2), h - 8);
      ctx.fillStyle = '#fff';
      ctx.fillText(p[0] + '. ' + p[1], at(a) + 3, y0 + h / 2 + 4, Math.max(at(b) - at(a) - 4, 8));
    });
    ctx.strokeStyle = '#000'; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(at(i), y0); ctx.lineTo(at(i), y0 + h); ctx.stroke();
  }

  function drawCharts(d, i) {
    const [x0, y0, w, h] = rect(L.charts), ph = h / CONFIG.panels.length;
    ctx.font = '11px system-ui, sans-serif';
    CONFIG.panels.forEach((panel, k) => {
      const top = y0 + k * ph + 16, height = ph - 30;
      const names = panel[1].filter((c) => d.series[c]);
      const values = [].concat(...names.map((c) => d.series[c])).filter((v) => v !== null && isFinite(v));
      const lo = Math.min(0, ...values), hi = panel[2] ? Math.min(Math.max(1, ...values), panel[2])
        : Math.max(1, ...values);
      const X = (j) => x0 + (d.n > 1 ? j / (d.n - 1) : 0) * w;
      const Y = (v) => top + height - (Math.min(v, hi) - lo) / (hi - lo) * height;
      ctx.strokeStyle = '#ccc'; ctx.lineWidth = 1; ctx.strokeRect(x0, top, w, height);
      let text = panel[0];
      if (panel[0].includes('TTC') && d.meta.pet_s !== null && d.meta.pet_s !== undefined) {
        text += ', PET ' + d.meta.pet_s.toFixed(2) + ' s';
      }
      ctx.fillStyle = '#222'; ctx.fillText(text + '  (' + lo.toFixed(0) + ' to ' + hi.toFixed(0) + ')', x0, top - 4);
      names.forEach((c, n) => {
        const v = d.series[c];
        ctx.strokeStyle = S.series[c]; ctx.lineWidth = 1.5;
        ctx.beginPath();
        let open = false;
        v.forEach((y, j) => {
          if (y === null) { open = false; return; }
          if (open) ctx.lineTo(X(j), Y(y)); else ctx.moveTo(X(j), Y(y));
          open = true;
        });
        ctx.stroke();
        const now = v[i] === null ? 'n/a' : v[i].toFixed(1);
        const name = CONFIG.series.find((s) => s[0] === c)[1];
        ctx.fillStyle = S.series[c];
        ctx.fillText(name + ' ' + now, x0 + 4 + n * (w / 2), top + 12);
      });
      ctx.strokeStyle = '#000'; ctx.lineWidth = 1;
      ctx.beginPath(); ctx.moveTo(X(i), top); ctx.lineTo(X(i), top + height); ctx.stroke();
    });
  }

  function show(i) {
    if (!scene) return;
    frame = Math.max(0, Math.min(scene.n - 1, i));
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    const state = drawMap(scene, frame);
    drawTimeline(scene, frame);
    drawCharts(scene, frame);
    slider.value = frame;
    const phase = scene.phases.filter((p) => p[2] !== null && p[2] <= frame && (p[3] === null || frame <= p[3]));
    label.textContent = 'frame ' + (frame + 1) + ' of ' + scene.n + ', t = ' + scene.t[frame].toFixed(2) + ' s'
      + (phase.length ? ', phase ' + phase.map((p) => p[0] + '. ' + p[1]).join(' + ') : ', outside the phases');
    dialog.dataset.frame = frame;
    shown = {
      match: scene.meta.id, frame: frame, n: scene.n,
      ego: [scene.ego.x[frame], scene.ego.y[frame]], egoPx: state.ego, actorPx: state.actor,
    };
  }

  function pause() {
    if (timer !== null) clearInterval(timer);
    timer = null;
    playButton.textContent = 'play';
  }

  function play() {
    if (!scene) return;
    if (frame >= scene.n - 1) show(0);
    pause();
    playButton.textContent = 'pause';
    timer = setInterval(() => { if (frame >= scene.n - 1) pause(); else show(frame + 1); },
                        Math.max(20, scene.meta.dt * 1000));
  }

  async function open(k) {
    pause();
    const mine = ++token;
    dialog.showModal();
    dialog.dataset.ready = '';
    title.textContent = 'loading ...';
    const s = await unpack('rp-' + k);
    if (s.map !== null && !(s.map in maps) && CONFIG.maps[s.map] !== undefined) {
      maps[s.map] = await unpack('rm-' + CONFIG.maps[s.map]);
    }
    if (mine !== token) return;
    scene = decode(s, s.map === null ? null : maps[s.map]);
    slider.max = scene.n - 1;
    title.textContent = s.scenario + ': drive ' + s.drive + ', ego ' + s.ego + ' (blue), actor ' + s.actor
      + ' (red), match ' + s.start_s.toFixed(1) + ' to ' + s.end_s.toFixed(1) + ' s';
    show(0);
    dialog.dataset.ready = s.id;
  }

  // what is on the screen, for tests and for the console
  window.logiqReplay = {
    open: open, play: play, pause: pause, show: (i) => show(i),
    get state() { return shown && Object.assign({ playing: timer !== null }, shown); },
  };
  // one listener for every row, however many matches the table has
  document.addEventListener('click', (event) => {
    const button = event.target.closest('button[data-replay]');
    if (button) open(button.dataset.replay);
  });
  playButton.addEventListener('click', () => (timer === null ? play() : pause()));
  document.getElementById('replay-back').addEventListener('click', () => { pause(); show(frame - 1); });
  document.getElementById('replay-next').addEventListener('click', () => { pause(); show(frame + 1); });
  document.getElementById('replay-close').addEventListener('click', () => { pause(); dialog.close(); });
  slider.addEventListener('input', () => { pause(); show(Number(slider.value)); });
  dialog.addEventListener('close', pause);
})();
