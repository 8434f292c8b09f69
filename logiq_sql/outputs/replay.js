// The report's match replay: decodes a scene of logiq_sql/outputs/replay.py (gzip + base64 JSON in a <script> tag, read
// only when the match is opened) and draws it on a canvas with the layout, colours and rules of replay.py's
// matplotlib renderer (LAYOUT, STYLE, KEY, SERIES, PANELS in the replay-config tag; viewCentre, scaleBar,
// actorNote and arrow mirror view_centres, scale_bar_m, actor_note and arrow_points there).
(function () {
  'use strict';
  const CONFIG = JSON.parse(document.getElementById('replay-config').textContent);
  const L = CONFIG.layout, S = CONFIG.style;
  const FONT = '11px system-ui, sans-serif', SMALL = '10px system-ui, sans-serif';
  const dialog = document.getElementById('replay');
  const canvas = document.getElementById('replay-canvas');
  const ctx = canvas.getContext('2d');
  const slider = document.getElementById('replay-slider');
  const label = document.getElementById('replay-frame');
  const title = document.getElementById('replay-title');
  const playButton = document.getElementById('replay-play');
  const maps = {};
  let scene = null, frame = 0, timer = null, token = 0, shown = null, texts = [];

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
    CONFIG.series.forEach((c) => { scale[c[0]] = c[3]; });
    const series = {};
    Object.keys(s.s).forEach((c) => { series[c] = s.s[c].map((v) => (v === null ? null : v * scale[c])); });
    const shift = map ? [map.origin[0], map.origin[1]] : [0, 0];
    const moved = (list) => list.map((r) => r.map((p) => [p[0] + shift[0], p[1] + shift[1]]));
    return {
      meta: s, n: n, t: frames.map((f) => s.t0 + (f - frames[0]) * s.dt),
      ego: actor(s.e, q, s.origin), actor: actor(s.a, q, s.origin),
      others: s.o.map((o) => Object.assign(actor(o, q, s.origin, n, o.i), { kind: o.k })),
      series: series, phases: s.p, bridged: new Set(s.b),
      lanes: map ? moved(rings(map.lanes, map.q)) : [], junctions: map ? moved(rings(map.junctions, map.q)) : [],
    };
  }

  function rect(part) {
    return [part[0] * canvas.width, part[1] * canvas.height, part[2] * canvas.width, part[3] * canvas.height];
  }

  // every text goes through here: drawn, and its box kept for the tests (window.logiqReplay.texts)
  function text(str, x, y, colour, opts) {
    const o = opts || {};
    ctx.font = o.font || FONT;
    ctx.fillStyle = colour;
    ctx.textAlign = o.align || 'left';
    ctx.textBaseline = o.baseline || 'alphabetic';
    const m = ctx.measureText(str);
    ctx.save();
    ctx.translate(x, y);
    if (o.rotate) ctx.rotate(o.rotate);
    ctx.fillText(str, 0, 0);
    ctx.restore();
    const w = m.actualBoundingBoxLeft + m.actualBoundingBoxRight;
    const h = m.actualBoundingBoxAscent + m.actualBoundingBoxDescent;
    let box = [x - m.actualBoundingBoxLeft, y - m.actualBoundingBoxAscent, w, h];
    if (o.rotate) box = [x - m.actualBoundingBoxAscent, y - m.actualBoundingBoxRight, h, w];  // -90 degrees
    texts.push({ text: str, x: box[0], y: box[1], w: box[2], h: box[3] });
    ctx.textAlign = 'left'; ctx.textBaseline = 'alphabetic';
    return box;
  }

  function polyline(toPx, pts, close) {
    ctx.beginPath();
    pts.forEach((p, k) => { const q = toPx(p[0], p[1]); if (k) ctx.lineTo(q[0], q[1]); else ctx.moveTo(q[0], q[1]); });
    if (close) ctx.closePath();
  }

  function corners(x, y, h, l, w) {
    const c = Math.cos(h), s = Math.sin(h);
    return [[1, 1], [1, -1], [-1, -1], [-1, 1]].map((p) => [
      x + p[0] * l / 2 * c - p[1] * w / 2 * s, y + p[0] * l / 2 * s + p[1] * w / 2 * c]);
  }

  // the heading: a shaft from the centre with a head at the front edge (replay.arrow_points)
  function arrow(x, y, h, l, w) {
    const head = Math.min(w * 0.8, l * 0.45), shaft = w * 0.12, tip = l / 2, c = Math.cos(h), s = Math.sin(h);
    return [[-l * 0.25, -shaft], [tip - head, -shaft], [tip - head, -head / 2], [tip, 0], [tip - head, head / 2],
      [tip - head, shaft], [-l * 0.25, shaft]].map((p) => [x + p[0] * c - p[1] * s, y + p[0] * s + p[1] * c]);
  }

  function box(toPx, x, y, h, l, w, fill, alpha, heading) {
    const pts = corners(x, y, h, l, w);
    ctx.globalAlpha = alpha;
    ctx.fillStyle = fill; ctx.strokeStyle = '#000'; ctx.lineWidth = 1;
    polyline(toPx, pts, true); ctx.fill(); ctx.stroke();
    if (heading) { ctx.fillStyle = '#fff'; polyline(toPx, arrow(x, y, h, l, w), true); ctx.fill(); }
    ctx.globalAlpha = 1;
    return pts.map((p) => toPx(p[0], p[1]));
  }

  function polygon(toPx, pts, fill, edge, alpha) {
    ctx.globalAlpha = alpha;
    polyline(toPx, pts, true);
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

  function viewCentre(d, i) {
    if (d.actor.x[i] === null) return [d.ego.x[i], d.ego.y[i]];
    return [(d.ego.x[i] + d.actor.x[i]) / 2, (d.ego.y[i] + d.actor.y[i]) / 2];
  }

  function scaleBar(width) {
    return [5, 10, 20, 50, 100, 200, 500].find((v) => v >= width / 6) || 1000;
  }

  // round tick values between lo and hi, about `count` of them
  function ticks(lo, hi, count) {
    if (!(hi > lo)) return [lo];
    const raw = (hi - lo) / count, p = Math.pow(10, Math.floor(Math.log10(raw)));
    const step = [1, 2, 2.5, 5, 10].map((m) => m * p).find((v) => v >= raw);
    const out = [];
    for (let v = Math.ceil(lo / step) * step; v <= hi + 1e-9; v += step) out.push(Math.round(v * 1e6) / 1e6);
    return out;
  }

  function drawMap(d, i) {
    const [x0, y0, w, h] = rect(L.map);
    const half = d.meta.view_m, k = w / (2 * half), [cx, cy] = viewCentre(d, i);
    const toPx = (x, y) => [x0 + w / 2 + (x - cx) * k, y0 + h / 2 - (y - cy) * k];
    ctx.save();
    ctx.beginPath(); ctx.rect(x0, y0, w, h); ctx.clip();
    ctx.fillStyle = S.background; ctx.fillRect(x0, y0, w, h);
    d.lanes.forEach((r) => polygon(toPx, r, S.lane_fill, S.lane_edge, 1));
    d.junctions.forEach((r) => polygon(toPx, r, S.junction_fill, S.junction_edge, S.junction_alpha));
    d.others.forEach((o) => {
      if (o.x[i] !== null) box(toPx, o.x[i], o.y[i], o.h[i], o.l, o.w, S.other, S.other_alpha, false);
    });
    path(toPx, d.actor.x, d.actor.y, i, S.actor);
    path(toPx, d.ego.x, d.ego.y, i, S.ego);
    const state = { ego: box(toPx, d.ego.x[i], d.ego.y[i], d.ego.h[i], d.ego.l, d.ego.w, S.ego, 1, true), actor: null };
    if (d.actor.x[i] !== null) {
      state.actor = box(toPx, d.actor.x[i], d.actor.y[i], d.actor.h[i], d.actor.l, d.actor.w, S.actor, 1, true);
    }
    ctx.restore();
    // the scale bar on a white ground in the lower left corner
    const bar = scaleBar(2 * half);
    ctx.fillStyle = 'rgba(255,255,255,.85)'; ctx.fillRect(x0 + 4, y0 + h - 26, bar * k + 12, 22);
    ctx.fillStyle = '#000'; ctx.fillRect(x0 + 10, y0 + h - 22, bar * k, 3);
    text(bar + ' m', x0 + 10 + bar * k / 2, y0 + h - 8, '#000', { align: 'center', font: SMALL });
    ctx.strokeStyle = '#999'; ctx.lineWidth = 1; ctx.strokeRect(x0, y0, w, h);
    // axes in map metres: ticks under and left of the map, labelled with the unit
    const xs = ticks(cx - half, cx + half, 6), hh = half * h / w, ys = ticks(cy - hh, cy + hh, 4);
    ctx.strokeStyle = '#000';
    xs.forEach((v) => {
      const p = toPx(v, cy)[0];
      if (p < x0 || p > x0 + w) return;
      ctx.beginPath(); ctx.moveTo(p, y0 + h); ctx.lineTo(p, y0 + h + 4); ctx.stroke();
      text(String(v), p, y0 + h + 15, '#333', { align: 'center', font: SMALL });
    });
    ys.forEach((v) => {
      const p = toPx(cx, v)[1];
      if (p < y0 || p > y0 + h) return;
      ctx.beginPath(); ctx.moveTo(x0 - 4, p); ctx.lineTo(x0, p); ctx.stroke();
      text(String(v), x0 - 6, p + 4, '#333', { align: 'right', font: SMALL });
    });
    text('x (m)', x0 + w / 2, y0 + h + 29, '#222', { align: 'center' });
    text('y (m)', x0 - 44, y0 + h / 2, '#222', { align: 'center', rotate: -Math.PI / 2 });
    state.view = [x0, y0, w, h];
    return state;
  }

  // rows of coloured swatches and names from x0 in the part, wrapped before the canvas's edge; [name, colour, mark]
  function key(part, entries) {
    const [x0, y0, , h] = rect(part);
    ctx.font = SMALL;
    const room = canvas.width - 8, widths = entries.map(([name]) => 16 + ctx.measureText(name).width + 14);
    const rows = widths.reduce((acc, w) => (acc.x + w > room ? { x: x0 + 8 + w, n: acc.n + 1 } : { x: acc.x + w, n: acc.n }),
      { x: x0 + 8, n: 1 }).n;
    let x = x0 + 8, y = y0 + h / 2 - (rows - 1) * 7;
    entries.forEach(([name, colour, mark], k) => {
      if (x + widths[k] > room && x > x0 + 8) { x = x0 + 8; y += 14; }
      ctx.fillStyle = colour;
      if (mark === 'bar') ctx.fillRect(x + 4, y - 6, 2, 12);
      else if (mark === 'arrow') {
        ctx.fillRect(x, y - 1, 8, 2);
        ctx.beginPath(); ctx.moveTo(x + 7, y - 4); ctx.lineTo(x + 12, y); ctx.lineTo(x + 7, y + 4); ctx.fill();
      } else { ctx.fillRect(x, y - 5, 12, 10); ctx.strokeStyle = '#555'; ctx.strokeRect(x, y - 5, 12, 10); }
      const b = text(name, x + 16, y + 4, '#222', { font: SMALL });
      x = b[0] + b[2] + 14;
    });
  }

  function timeAxis(d, x0, w) {
    const lo = d.t[0], hi = d.t[d.n - 1] + d.meta.dt;
    return { lo: lo, hi: hi, at: (t) => x0 + (t - lo) / (hi - lo) * w };
  }

  function context(d, T, top, height) {
    ctx.fillStyle = S.context;
    const m = d.meta;
    if (m.start_s > T.lo) ctx.fillRect(T.at(T.lo), top, T.at(m.start_s) - T.at(T.lo), height);
    if (T.hi > m.end_s + m.dt) ctx.fillRect(T.at(m.end_s + m.dt), top, T.at(T.hi) - T.at(m.end_s + m.dt), height);
  }

  function timeTicks(T, y, labelled) {
    ctx.strokeStyle = '#000'; ctx.lineWidth = 1;
    ticks(T.lo, T.hi, 6).forEach((v) => {
      const p = T.at(v);
      ctx.beginPath(); ctx.moveTo(p, y); ctx.lineTo(p, y + 4); ctx.stroke();
      if (labelled) text(String(v), p, y + 15, '#333', { align: 'center', font: SMALL });
    });
  }

  function drawTimeline(d, i) {
    const [x0, y0, w, h] = rect(L.timeline), T = timeAxis(d, x0, w);
    ctx.fillStyle = '#f4f4f4'; ctx.fillRect(x0, y0, w, h);
    context(d, T, y0, h);
    d.phases.forEach((p) => {
      const a = p[2] === null ? 0 : p[2], b = p[3] === null ? d.n - 1 : p[3];
      ctx.fillStyle = S.phases[(p[0] - 1) % S.phases.length];
      ctx.fillRect(T.at(d.t[a]), y0 + 0.15 * h, T.at(d.t[b] + d.meta.dt) - T.at(d.t[a]), 0.7 * h);
    });
    ctx.fillStyle = S.bridged;
    d.bridged.forEach((j) => ctx.fillRect(T.at(d.t[j] + d.meta.dt / 2) - 1, y0 + 0.3 * h, 2, 0.4 * h));
    ctx.strokeStyle = '#999'; ctx.lineWidth = 1; ctx.strokeRect(x0, y0, w, h);
    timeTicks(T, y0 + h, true);
    text(CONFIG.time_label, x0 + w / 2, y0 + h + 29, '#222', { align: 'center' });
    ctx.strokeStyle = '#000'; ctx.lineWidth = 2;
    ctx.beginPath(); ctx.moveTo(T.at(d.t[i]), y0); ctx.lineTo(T.at(d.t[i]), y0 + h); ctx.stroke();
    // the phases' names in a key, never on the bars: a short phase has no room for its name
    const entries = d.phases.map((p) => [p[0] + '. ' + p[1], S.phases[(p[0] - 1) % S.phases.length]]);
    entries.push(['context (' + CONFIG.margin_s + ' s either side)', S.context]);
    if (d.bridged.size) entries.push(['bridged frame', S.bridged, 'bar']);
    if (d.meta.hw.lo !== null) entries.push(['headway range tested', S.band]);
    key(L.phase_key, entries);
  }

  function actorNote(d, i) {
    if (d.actor.x[i] !== null) return null;
    const seen = d.actor.x.map((v, j) => (v === null ? -1 : j)).filter((j) => j >= 0);
    if (!seen.length) return 'actor not tracked';
    if (i < seen[0]) return 'actor track starts at t=' + d.t[seen[0]].toFixed(1) + ' s';
    if (i > seen[seen.length - 1]) return 'actor track ends at t=' + d.t[seen[seen.length - 1]].toFixed(1) + ' s';
    return 'actor not tracked here';
  }

  function drawCharts(d, i) {
    const [x0, y0, w, h] = rect(L.charts), rows = CONFIG.panels.length, gap = 0.045 * canvas.height;
    const ph = (h + gap) / rows - gap, T = timeAxis(d, x0, w), note = actorNote(d, i);
    const hwName = d.meta.hw.column === 'follow_headway_s' ? 'follow headway' : 'headway';
    CONFIG.panels.forEach((panel, k) => {
      const top = y0 + k * (h + gap) / rows, cap = panel[2];
      const [lo, hi0] = d.meta.y[k], hi = cap ? hi0 : hi0 * 1.05;
      const Y = (v) => top + ph - (Math.min(v, hi) - lo) / (hi - lo) * ph;
      ctx.fillStyle = '#fff'; ctx.fillRect(x0, top, w, ph);
      context(d, T, top, ph);
      if (panel[1].includes('headway_s') && d.meta.hw.lo !== null) {
        ctx.fillStyle = S.band;
        ctx.fillRect(x0, Y(Math.min(d.meta.hw.hi, cap)), w, Y(d.meta.hw.lo) - Y(Math.min(d.meta.hw.hi, cap)));
      }
      ctx.strokeStyle = '#999'; ctx.lineWidth = 1; ctx.strokeRect(x0, top, w, ph);
      ticks(lo, hi, 4).forEach((v, j, all) => {
        ctx.strokeStyle = '#000';
        ctx.beginPath(); ctx.moveTo(x0 - 4, Y(v)); ctx.lineTo(x0, Y(v)); ctx.stroke();
        const capped = cap && j === all.length - 1 && v >= cap;
        text((capped ? '\u2265' : '') + v, x0 - 6, Y(v) + 4, '#333', { align: 'right', font: SMALL });
      });
      text(panel[0], x0 - 40, top + ph / 2, '#222', { align: 'center', rotate: -Math.PI / 2 });
      timeTicks(T, top + ph, k === rows - 1);
      if (k === rows - 1) text(CONFIG.time_label, x0 + w / 2, top + ph + 29, '#222', { align: 'center' });
      const names = panel[1].filter((c) => d.series[c]);
      names.forEach((c, n) => {
        const v = d.series[c];
        ctx.strokeStyle = S.series[c]; ctx.lineWidth = 1.5;
        ctx.beginPath();
        let open = false;
        v.forEach((y, j) => {
          if (y === null) { open = false; return; }
          if (open) ctx.lineTo(T.at(d.t[j]), Y(y)); else ctx.moveTo(T.at(d.t[j]), Y(y));
          open = true;
        });
        ctx.stroke();
        if (c === 'headway_s') {  // bridged frames: a cross at the value (on the axis where it is undefined)
          ctx.strokeStyle = S.bridged; ctx.lineWidth = 1;
          d.bridged.forEach((j) => {
            const px = T.at(d.t[j]), py = Y(v[j] === null ? Math.max(lo, 0) : v[j]);
            ctx.beginPath(); ctx.moveTo(px - 3, py - 3); ctx.lineTo(px + 3, py + 3);
            ctx.moveTo(px - 3, py + 3); ctx.lineTo(px + 3, py - 3); ctx.stroke();
          });
        }
        const spec = CONFIG.series.find((s) => s[0] === c);
        const name = c === 'headway_s' ? hwName : spec[1];
        let value;
        if (note && c !== 'ego_speed_mph') value = n === 0 ? note : '';
        else if (v[i] === null) value = name + ' undefined';
        else value = name + ' ' + v[i].toFixed(1) + ' ' + spec[2] + (cap && v[i] > cap ? ' (axis ends at ' + cap + ')' : '');
        // the value line above the panel, one series at each end: never under a curve
        if (value) text(value, n === 0 ? x0 : x0 + w, top - 4, S.series[c], { align: n === 0 ? 'left' : 'right' });
      });
      ctx.strokeStyle = '#000'; ctx.lineWidth = 1;
      ctx.beginPath(); ctx.moveTo(T.at(d.t[i]), top); ctx.lineTo(T.at(d.t[i]), top + ph); ctx.stroke();
    });
  }

  function show(i) {
    if (!scene) return;
    frame = Math.max(0, Math.min(scene.n - 1, i));
    texts = [];
    ctx.clearRect(0, 0, canvas.width, canvas.height);
    ctx.fillStyle = '#fff'; ctx.fillRect(0, 0, canvas.width, canvas.height);
    const state = drawMap(scene, frame);
    key(L.key, CONFIG.key.map(([name, colour]) => [name, S[colour]]).concat([['heading', '#000', 'arrow']]));
    drawTimeline(scene, frame);
    drawCharts(scene, frame);
    slider.value = frame;
    const phase = scene.phases.filter((p) => p[2] !== null && p[2] <= frame && (p[3] === null || frame <= p[3]));
    label.textContent = 'frame ' + (frame + 1) + ' of ' + scene.n + ', t = ' + scene.t[frame].toFixed(2) + ' s'
      + (phase.length ? ', phase ' + phase.map((p) => p[0] + '. ' + p[1]).join(' + ') : ', outside the phases');
    dialog.dataset.frame = frame;
    shown = {
      match: scene.meta.id, frame: frame, n: scene.n, t: scene.t[frame],
      inMatch: scene.t[frame] >= scene.meta.start_s - 1e-6 && scene.t[frame] <= scene.meta.end_s + 1e-6,
      ego: [scene.ego.x[frame], scene.ego.y[frame]], egoPx: state.ego[0], actorPx: state.actor && state.actor[0],
      egoBox: state.ego, actorBox: state.actor, view: state.view, texts: texts,
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
    title.replaceChildren();
    s.titles.forEach((line, k) => {
      const part = document.createElement(k ? 'span' : 'b');
      part.textContent = line;
      title.append(part, k ? '' : document.createElement('br'));
    });
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
