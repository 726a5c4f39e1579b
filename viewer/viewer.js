// The viewer's page: the list of databases and materials at /viewer/, and at /viewer/{db}/{material}
// the material streamed (streaming.js), decoded on the GPU (renderer.js) and lit with the sliders or
// the mouse. ?scene=plane|sphere&light=T,P&view=T,P&tiles=K set the first view (docs/viewer.md).
import { streamMaterial, events, logEvent } from './streaming.js';
import { MaterialRenderer } from './renderer.js';

window.viewerEvents = events;
const $ = (id) => document.getElementById(id);

async function getJson(url) {
  const r = await fetch(url, { cache: 'no-store' });
  if (!r.ok) throw new Error(`${url}: HTTP ${r.status}`);
  return r.json();
}

const text = (s) => document.createTextNode(String(s));
function element(tag, children = [], attrs = {}) {
  const e = document.createElement(tag);
  Object.assign(e, attrs);
  for (const c of children) e.append(typeof c === 'string' || typeof c === 'number' ? text(c) : c);
  return e;
}
const kib = (n) => (n >= 1 << 20 ? `${(n / (1 << 20)).toFixed(1)} MiB` : n >= 1024 ? `${(n / 1024).toFixed(1)} KiB` : `${n} B`);
const viewerUrl = (db, m) => `/viewer/${encodeURIComponent(db)}/${encodeURIComponent(m)}`;

async function showListing() {
  $('listing').hidden = false;
  const { databases } = await getJson('/v1/databases');
  const box = $('databases');
  box.textContent = databases.length ? '' : 'No database has been published yet.';
  for (const d of databases) {
    const info = await getJson(`/v1/databases/${encodeURIComponent(d.name)}`);
    const rows = info.newest.materials.map((m) => element('tr', [
      element('td', [element('a', [m.name], { href: viewerUrl(d.name, m.name) })]),
      element('td', [`${m.width} x ${m.height}`]),
      element('td', [`added in version ${m.version_added}`]),
    ]));
    box.append(element('h2', [`${d.name} `, element('small', [`version ${d.version}, ${kib(d.size)}, ratio ${d.ratio.toFixed(1)}`])]),
               element('table', rows, { className: 'databases' }));
  }
  document.body.dataset.state = 'listed';
}

// The catalogue's numbers for one material (GET /v1/databases/{db}): the database's size and ratio,
// the material's size, and the metrics of its compression report (the encoder's dissimilarity,
// code-book sizes, time; a report's "metrics" object too, when it has one). `streamed`, once known,
// adds the bytes this material needs and the ratio of its raw bytes to them.
function showReadout(info, name, streamed) {
  const m = info.newest.materials.find((x) => x.name === name) || {};
  const report = m.report || {};
  const rows = [['database', `${info.name}, version ${info.newest.version}`], ['database size', kib(info.newest.size)],
                ['database ratio', Number(info.newest.ratio || 0).toFixed(1)]];
  if (m.width) rows.push(['material', `${m.width} x ${m.height} texels, ${report.dynamic || ''}, ${kib(m.raw_bytes)} measured`]);
  if (streamed) rows.push(['bytes for it', `${kib(streamed)} (head + its sections)`], ['its ratio', (m.raw_bytes / streamed).toFixed(1)]);
  if (report.dissimilarity) rows.push(['dissimilarity', `mean ${report.dissimilarity.mean.toFixed(3)}, max ${report.dissimilarity.max.toFixed(3)}`]);
  for (const [k, v] of Object.entries(report.metrics || {}))
    if (typeof v === 'number') rows.push([k.replaceAll('_', ' '), v.toPrecision(4)]);
  if (report.codebook_sizes) rows.push(['code-books', Object.entries(report.codebook_sizes).map(([k, v]) => `${k} ${v}`).join(', ')]);
  if (report.seconds && report.seconds.schedule_total) rows.push(['encoded in', `${report.seconds.schedule_total.toFixed(1)} s`]);
  $('readout').replaceChildren(...rows.map(([k, v]) => element('tr', [element('td', [k]), element('td', [v])])));
}

function pair(param, fallback) {
  const parts = (param || '').split(',').map(Number);
  return parts.length === 2 && parts.every(Number.isFinite) ? parts : fallback;
}

async function showMaterial(db, name) {
  $('material').hidden = false;
  $('where').textContent = `${db} / ${name}`;
  document.title = `${name} - btfvq viewer`;
  const q = new URLSearchParams(location.search);
  const view = {
    scene: q.get('scene') === 'sphere' ? 'sphere' : 'plane',
    light: pair(q.get('light'), [30, 135]),
    view: pair(q.get('view'), [0, 0]),
    tiles: Number(q.get('tiles')) || 1,
  };
  const renderer = new MaterialRenderer($('canvas'));
  let ready = false;
  const draw = () => { if (ready) renderer.draw(view); };
  bindControls(view, draw);
  const catalogue = getJson(`/v1/databases/${encodeURIComponent(db)}`);
  catalogue.then((info) => showReadout(info, name)).catch(() => {});

  const started = performance.now();
  const { total } = await streamMaterial(db, name, {
    onProgress: (p) => {
      $('progress').textContent = `${kib(p.received)} of ${kib(p.total)} received (file ${kib(p.fileSize)}), sections ${p.sections} of ${p.sectionCount}`;
    },
    onCodebooks: (books, grid) => renderer.setCodebooks(books, grid),
    onFrame: (p6) => {
      renderer.setP6(p6.header, p6.entries, p6.scales, p6.texelsReady, p6.scalesReady);
      ready = true;
      draw();
      logEvent('frame', { texels: p6.texelsReady, scales: p6.scalesReady, final: p6.final });
    },
  });
  catalogue.then((info) => showReadout(info, name, total)).catch(() => {});
  $('progress').textContent += `, done in ${((performance.now() - started) / 1000).toFixed(2)} s`;
  document.body.dataset.state = 'final';
}

function bindControls(view, draw) {
  const sliders = { 'light-theta': [view.light, 0], 'light-phi': [view.light, 1], 'view-theta': [view.view, 0], 'view-phi': [view.view, 1] };
  const refresh = () => {
    for (const [id, [arr, k]] of Object.entries(sliders)) {
      $(id).value = arr[k];
      $(id).nextElementSibling.value = `${arr[k]}\u00b0`;
    }
    $('tiles').value = view.tiles;
    $('tiles').nextElementSibling.value = view.tiles;
    $('scene').value = view.scene;
    // On the sphere the light is in the camera frame and may come from behind.
    $('light-theta').max = view.scene === 'sphere' ? 180 : 90;
  };
  for (const [id, [arr, k]] of Object.entries(sliders))
    $(id).addEventListener('input', (e) => { arr[k] = Number(e.target.value); refresh(); draw(); });
  $('tiles').addEventListener('input', (e) => { view.tiles = Number(e.target.value); refresh(); draw(); });
  $('scene').addEventListener('change', (e) => { view.scene = e.target.value; refresh(); draw(); });
  // Dragging: the light comes from where the pointer is, seen from above the sample.
  const canvas = $('canvas');
  const fromPointer = (e) => {
    const r = canvas.getBoundingClientRect();
    const x = ((e.clientX - r.left) / r.width) * 2 - 1, y = 1 - ((e.clientY - r.top) / r.height) * 2;
    const radius = Math.min(1, Math.hypot(x, y));
    view.light[0] = Math.round(radius * (view.scene === 'sphere' ? 180 : 90) * 2) / 2;
    view.light[1] = Math.round(((Math.atan2(y, x) * 180) / Math.PI + 360) % 360);
    refresh();
    draw();
  };
  canvas.addEventListener('pointerdown', (e) => { canvas.setPointerCapture(e.pointerId); fromPointer(e); });
  canvas.addEventListener('pointermove', (e) => { if (e.buttons) fromPointer(e); });
  refresh();
}

async function main() {
  const parts = location.pathname.replace(/^\/viewer\/?/, '').split('/').filter(Boolean).map(decodeURIComponent);
  try {
    if (parts.length === 2) await showMaterial(parts[0], parts[1]);
    else await showListing();
  } catch (e) {
    logEvent('error', { message: String(e.message || e) });
    document.body.dataset.state = 'error';
    document.body.append(element('p', [`error: ${e.message || e}`], { className: 'error' }));
  }
}

main();
