// storetrack live view: draws the host's snapshots (GET /api/scene once, then the event stream
// /events). Plain JavaScript, no library: everything the page needs is served by the host.
'use strict';

const RESIDUAL_SCALE = 50;     // residual vectors drawn 50x their length
const CHART_SECONDS = 10;      // strip chart span
const CLOCK_STATES = ['free-running', 'locking', 'locked', 'holdover'];
const STATUS_BITS = ['valid', 'rigid_body_failed', 'extrapolated', 'clock_not_locked',
                     'camera_missing', 'degraded_geometry', 'single_view'];
const UNIT_STATUS_BITS = ['capturing', 'maintenance_mode', 'trigger_master', 'can_bus_off',
                          'camera_error', 'trigger_error', 'centroid_error'];

const state = { scene: null, cameras: new Map(), history: [], lastSampleSeq: null,
                events: 0, lastEventAt: 0 };
window.storetrackLive = state;  // for a person at the browser console

function el(tag, attrs = {}, text) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
  if (text !== undefined) e.textContent = text;
  return e;
}

function fixed(v, digits) {
  return (v === null || v === undefined || !isFinite(v)) ? '—' : Number(v).toFixed(digits);
}

function buildCameras(scene) {
  const host = document.getElementById('cameras');
  host.textContent = '';
  for (const c of scene.cameras) {
    const box = el('div', { class: 'camera', id: 'camera-box-' + c.camera_id });
    const title = el('h3');
    title.append(el('span', {}, 'camera ' + c.camera_id + ' (unit ' + c.unit_id + ')'),
                 el('span', { class: 'state' }, 'no data'));
    // Canvas pixels = image pixels / scale: marks are drawn in image coordinates.
    const scale = Math.max(1, Math.ceil(c.width / 640));
    const canvas = el('canvas', { id: 'camera-' + c.camera_id, width: Math.round(c.width / scale),
                                  height: Math.round(c.height / scale),
                                  'data-camera-id': c.camera_id, 'data-marks-drawn': 0 });
    const info = el('div', { class: 'info' }, '');
    box.append(title, canvas, info);
    host.append(box);
    state.cameras.set(c.camera_id, { meta: c, scale, canvas, info, status: title.lastChild });
  }
  document.getElementById('residual-scale').textContent = RESIDUAL_SCALE;
  document.getElementById('chart-seconds').textContent = CHART_SECONDS;
}

// The coverage overlay, under everything else: the store marks' hull at each pose of the
// configured envelope (host.json live.store_envelope), red where a mark leaves the image.
function drawCoverage(g, outlines, X, Y) {
  for (const o of outlines) {
    if (o.hull.length === 0) continue;
    g.beginPath();
    g.moveTo(X(o.hull[0][0]), Y(o.hull[0][1]));
    for (const [x, y] of o.hull.slice(1)) g.lineTo(X(x), Y(y));
    g.closePath();
    g.fillStyle = o.leaves_image ? 'rgba(255, 107, 107, 0.10)' : 'rgba(89, 183, 255, 0.08)';
    g.strokeStyle = o.leaves_image ? 'rgba(255, 107, 107, 0.6)' : 'rgba(89, 183, 255, 0.35)';
    g.fill();
    g.stroke();
  }
}

function drawCamera(view, cam) {
  const { canvas, scale, meta } = view;
  const g = canvas.getContext('2d');
  g.clearRect(0, 0, canvas.width, canvas.height);
  g.strokeStyle = '#2c353d';
  g.strokeRect(0.5, 0.5, canvas.width - 1, canvas.height - 1);
  // Pixel centres at integers, the image edge at -0.5 (docs/conventions.md).
  const X = (x) => (x + 0.5) / scale, Y = (y) => (y + 0.5) / scale;
  drawCoverage(g, cam.coverage || [], X, Y);
  view.canvas.dataset.coverageOutlines = (cam.coverage || []).length;
  g.lineWidth = 1;
  g.strokeStyle = '#8aa0b4';
  for (const [id, x, y] of cam.expected_pylon) {
    g.strokeRect(X(x) - 6, Y(y) - 6, 12, 12);
  }
  g.strokeStyle = '#59b7ff';
  for (const [id, x, y] of cam.expected_store) {
    g.beginPath();
    g.moveTo(X(x), Y(y) - 7); g.lineTo(X(x) + 7, Y(y)); g.lineTo(X(x), Y(y) + 7);
    g.lineTo(X(x) - 7, Y(y)); g.closePath(); g.stroke();
  }
  let drawn = 0;
  g.font = '11px ui-monospace, monospace';
  for (const m of cam.marks) {
    const x = X(m.x), y = Y(m.y);
    if (m.id >= 0) {
      g.fillStyle = m.excluded ? '#f39c34' : '#62d26f';
      g.beginPath(); g.arc(x, y, 3.5, 0, 2 * Math.PI); g.fill();
      g.fillText(String(m.id), x + 6, y - 5);
      if (m.rx !== undefined) {
        g.strokeStyle = '#f0f0f0';
        g.beginPath(); g.moveTo(x, y);
        g.lineTo(x + m.rx * RESIDUAL_SCALE / scale, y + m.ry * RESIDUAL_SCALE / scale);
        g.stroke();
      }
    } else {
      g.strokeStyle = '#ff6b6b';
      g.beginPath();
      g.moveTo(x - 4, y - 4); g.lineTo(x + 4, y + 4); g.moveTo(x + 4, y - 4); g.lineTo(x - 4, y + 4);
      g.stroke();
    }
    ++drawn;
  }
  canvas.dataset.marksDrawn = drawn;
  canvas.dataset.markCount = cam.mark_count;
  canvas.dataset.triggerSeq = cam.delivered ? cam.trigger_seq : '';
  const identified = cam.marks.filter((m) => m.id >= 0).length;
  const clock = cam.delivered ? (CLOCK_STATES[cam.clock_state] || 'unknown') : '—';
  view.status.textContent = cam.delivered ? clock : 'missing';
  view.status.className = 'state ' + (!cam.delivered ? 'bad' : cam.clock_state === 2 ? 'ok' : 'warn');
  const k = cam.counters;
  view.info.textContent =
      (cam.delivered ? 'seq ' + cam.trigger_seq + '  exposure ' +
                       fixed(cam.exposure_duration_ns / 1000, 0) + ' us  ' : 'not in this exposure  ') +
      'marks ' + cam.mark_count + ' (' + identified + ' identified)\n' +
      'received ' + k.received + '  used ' + k.used + '  missing ' + k.missing + '  late ' + k.late +
      '  time mismatch ' + k.time_mismatch + '  duplicate ' + k.duplicate + '  quarantined ' +
      k.quarantined;
}

function fillTable(tbody, rows) {
  tbody.textContent = '';
  for (const row of rows) {
    const tr = el('tr');
    for (const cell of row) {
      const td = el('td', cell.attrs || {}, cell.text !== undefined ? cell.text : cell);
      tr.append(td);
    }
    tbody.append(tr);
  }
}

function drawSample(s) {
  const table = document.getElementById('sample');
  const bits = document.getElementById('status-bits');
  if (!s) { fillTable(table.tBodies[0], [['no sample yet']]); return; }
  const k = s.coverage_factor;
  const mm = (v) => v * 1000, deg = (v) => v * 180 / Math.PI;
  const rows = [['trigger_seq', { text: String(s.trigger_seq), attrs: { id: 'sample-trigger_seq' } }, '']];
  for (const [axis, conv, unit, digits] of [['x', mm, 'mm', 3], ['y', mm, 'mm', 3], ['z', mm, 'mm', 3],
                                          ['yaw', deg, 'deg', 4], ['pitch', deg, 'deg', 4],
                                          ['roll', deg, 'deg', 4]]) {
    const suffix = unit === 'mm' ? '_m' : '_rad';
    const v = s[axis + suffix], u = s['u_' + axis + suffix];
    rows.push([axis + ' [' + unit + ']',
               { text: fixed(v === null ? null : conv(v), digits), attrs: { id: 'sample-' + axis } },
               { text: '± ' + fixed(u === null ? null : conv(k * u), digits),
                 attrs: { id: 'sample-U_' + axis } }]);
  }
  rows.push(['cameras / store marks / pylon marks', '',
             s.cameras_used + ' / ' + s.marks_used + ' / ' + s.pylon_marks_used]);
  rows.push(['k', '', fixed(k, 1)]);
  fillTable(table.tBodies[0], rows);
  table.dataset.triggerSeq = s.trigger_seq;
  bits.textContent = '';
  STATUS_BITS.forEach((name, i) => {
    const set = (s.status >> i) & 1;
    bits.append(el('span', { class: (set ? 'set ' : '') + name }, name));
  });
}

function drawRig(snap) {
  const rig = document.getElementById('rig');
  rig.tHead.innerHTML = '<tr><th>camera</th><th>unit</th><th>clock (last seen)</th><th>marks</th>' +
      '<th>received</th><th>used</th><th>missing</th><th>late</th><th>dropped other</th></tr>';
  fillTable(rig.tBodies[0], snap.cameras.map((c) => {
    const k = c.counters;
    const other = k.time_mismatch + k.duplicate + k.spoofed + k.quarantined;
    // The clock state of the camera's newest observation, and how long ago it was seen.
    const seen = c.last_seen_age_ms === undefined ? null : c.last_seen_age_ms;
    const clock = seen === null ? 'never seen'
        : (CLOCK_STATES[c.last_clock_state] || 'unknown') + ' (' + fixed(seen / 1000, 1) + ' s)';
    const stale = seen === null || seen > 1000;
    return [String(c.camera_id), String(c.unit_id),
            { text: clock, attrs: { class: stale ? 'bad' : c.last_clock_state === 2 ? 'ok' : 'warn' } },
            String(c.mark_count), String(k.received), String(k.used),
            { text: String(k.missing), attrs: { class: k.missing ? 'nonzero' : '' } },
            { text: String(k.late), attrs: { class: k.late ? 'nonzero' : '' } },
            { text: String(other), attrs: { class: other ? 'nonzero' : '' } }];
  }));
  const units = document.getElementById('units');
  units.tHead.innerHTML = '<tr><th>unit</th><th>health</th><th>clock</th><th>PTP offset</th>' +
      '<th>sensor / board</th><th>frames dropped</th><th>trigger missing</th><th>link errors</th></tr>';
  fillTable(units.tBodies[0], snap.units.map((u) => {
    if (!u.heard) return [String(u.unit_id), { text: 'no health report', attrs: { class: 'warn' } },
                          '—', '—', '—', '—', '—', '—'];
    const flags = UNIT_STATUS_BITS.filter((_, i) => (u.status >> i) & 1).join(' ');
    return [String(u.unit_id), { text: fixed(u.age_ms / 1000, 1) + ' s ago ' + flags },
            { text: CLOCK_STATES[u.clock_state] || 'unknown',
              attrs: { class: u.clock_state === 2 ? 'ok' : 'warn' } },
            u.ptp_offset_ns === null ? '—' : u.ptp_offset_ns + ' ns',
            fixed(u.sensor_temp_c, 1) + ' / ' + fixed(u.board_temp_c, 1) + ' °C',
            fixed(u.frames_dropped, 0), fixed(u.triggers_missing, 0),
            u.link_tx_errors === null ? '—' : fixed(u.link_tx_errors + u.link_tx_dropped, 0)];
  }));
  fillTable(document.getElementById('aligner').tBodies[0],
            Object.entries(snap.aligner).map(([name, v]) =>
              [name, { text: String(v), attrs: { class: v && name.startsWith('dropped') ? 'nonzero' : '' } }]));
  const t = snap.totals, sv = snap.server;
  fillTable(document.getElementById('totals').tBodies[0], [
    ['exposures processed', String(t.exposures)], ['samples written', String(t.samples_written)],
    ['valid samples', String(t.valid_samples)], ['samples withheld', String(t.samples_withheld)],
    ['health messages', String(t.health_messages)],
    ['live clients (peak, refused, dropped)',
     sv.clients + ' (' + sv.clients_peak + ', ' + sv.clients_refused + ', ' + sv.clients_dropped + ')']]);
}

function recordHistory(s) {
  const now = performance.now() / 1000;
  if (s && s.trigger_seq !== state.lastSampleSeq && s.x_m !== null) {
    state.lastSampleSeq = s.trigger_seq;
    const k = s.coverage_factor;
    state.history.push({ t: now, v: [s.x_m, s.y_m, s.z_m],
                         U: [k * s.u_x_m, k * s.u_y_m, k * s.u_z_m] });
  }
  while (state.history.length && state.history[0].t < now - CHART_SECONDS) state.history.shift();
  drawChart(now);
}

function drawChart(now) {
  const canvas = document.getElementById('chart');
  const g = canvas.getContext('2d');
  g.clearRect(0, 0, canvas.width, canvas.height);
  const h = state.history, rowH = canvas.height / 3, left = 64;
  const colors = ['#ff8f70', '#7ee081', '#6cb8ff'];
  g.font = '11px ui-monospace, monospace';
  for (let a = 0; a < 3; ++a) {
    const top = a * rowH;
    g.strokeStyle = '#2c353d';
    g.strokeRect(left + 0.5, top + 0.5, canvas.width - left - 1, rowH - 4);
    g.fillStyle = '#9fb3c4';
    g.fillText(['x', 'y', 'z'][a] + ' [m]', 4, top + 12);
    if (!h.length) continue;
    let lo = Infinity, hi = -Infinity;
    for (const p of h) { lo = Math.min(lo, p.v[a] - p.U[a]); hi = Math.max(hi, p.v[a] + p.U[a]); }
    if (!(hi > lo)) { hi = lo + 1e-3; }
    const pad = (hi - lo) * 0.1; lo -= pad; hi += pad;
    g.fillText(hi.toFixed(4), 4, top + 26); g.fillText(lo.toFixed(4), 4, top + rowH - 8);
    const X = (t) => left + (canvas.width - left) * (1 - (now - t) / CHART_SECONDS);
    const Y = (v) => top + (rowH - 4) * (hi - v) / (hi - lo);
    g.fillStyle = colors[a] + '40';
    g.beginPath();
    h.forEach((p, i) => (i ? g.lineTo : g.moveTo).call(g, X(p.t), Y(p.v[a] + p.U[a])));
    for (let i = h.length - 1; i >= 0; --i) g.lineTo(X(h[i].t), Y(h[i].v[a] - h[i].U[a]));
    g.closePath(); g.fill();
    g.strokeStyle = colors[a];
    g.beginPath();
    h.forEach((p, i) => (i ? g.lineTo : g.moveTo).call(g, X(p.t), Y(p.v[a])));
    g.stroke();
  }
}

function render(snap) {
  const e = snap.exposure;
  document.getElementById('exposure').textContent =
      'exposure ' + e.trigger_seq + (e.sample_written ? '' : ' (no sample)') +
      (e.closed_by_timeout ? ', partial' : '') + ' · ' + e.cameras_used + ' cameras used · snapshot ' +
      snap.publication;
  for (const cam of snap.cameras) {
    const view = state.cameras.get(cam.camera_id);
    if (view) drawCamera(view, cam);
  }
  drawSample(snap.sample);
  drawRig(snap);
  recordHistory(snap.sample);
  document.body.dataset.publication = snap.publication;
}

function connect() {
  const status = document.getElementById('connection');
  const source = new EventSource('/events');
  source.addEventListener('snapshot', (ev) => {
    state.events += 1;
    state.lastEventAt = performance.now();
    status.textContent = 'live';
    status.className = 'ok';
    render(JSON.parse(ev.data));
  });
  source.onerror = () => {
    status.textContent = 'disconnected (retrying)';
    status.className = 'bad';
  };
  // No event for 2 s while connected: the host has nothing new (no exposures), say so.
  setInterval(() => {
    if (state.events && performance.now() - state.lastEventAt > 2000 && status.className === 'ok') {
      status.textContent = 'live, no new exposure';
      status.className = 'warn';
    }
  }, 500);
}

fetch('/api/scene').then((r) => r.json()).then((scene) => {
  state.scene = scene;
  buildCameras(scene);
  connect();
}).catch((err) => {
  document.getElementById('connection').textContent = 'cannot load the scene: ' + err;
});
