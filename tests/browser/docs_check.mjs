#!/usr/bin/env node
// Swagger UI (/docs) checked in a real headless Chromium, as a user meets
// it: the page loads from the binary with no request leaving the machine,
// lists the operations, shows the seed problem as the example, and "Try
// it out" posts to this service and shows 200, 422 and 400 answers. Run by
// scripts/browser_check.sh (part of scripts/test.sh).
//
// Usage: node docs_check.mjs BASE_URL [--behind-prefix /PREFIX]
//                           [--resolve HOST] [--shots DIR] [--chromium PATH]
//   BASE_URL  the service, e.g. http://127.0.0.1:8080 (no trailing slash)
//   --behind-prefix /PREFIX  put a reverse proxy in front that serves the
//             service under PREFIX and answers 404 to anything outside it
//             (like nginx's `location /PREFIX/ { proxy_pass BASE/; }`, but
//             without rewriting Location headers), and check through it
//   --resolve HOST  open the page as http://HOST:PORT/... with HOST mapped
//             to 127.0.0.1 inside Chromium: Swagger UI treats localhost and
//             127.0.0.1 specially (it skipped its online validator there)
//   --shots DIR  screenshots of each step (default: a new temporary folder)
// Requests to another origin are recorded and aborted before they leave
// the machine, and fail the check.
// Exit status: 0 if every check passed, 1 if any failed, 2 on a usage error.

import { mkdirSync, mkdtempSync } from 'node:fs';
import { readFile, rm } from 'node:fs/promises';
import http from 'node:http';
import os from 'node:os';
import path from 'node:path';
import { chromium } from 'playwright-core';

// ---- arguments ----
const argv = process.argv.slice(2);
const opt = { shots: null, chromium: '/usr/bin/chromium', resolve: null, prefix: null };
let baseArg = null;
for (let i = 0; i < argv.length; i++) {
  const a = argv[i];
  if (a === '--shots') opt.shots = argv[++i];
  else if (a === '--chromium') opt.chromium = argv[++i];
  else if (a === '--resolve') opt.resolve = argv[++i];
  else if (a === '--behind-prefix') opt.prefix = argv[++i];
  else if (!a.startsWith('--') && !baseArg) baseArg = a;
  else { console.error(`unknown argument ${a}`); process.exit(2); }
}
if (!baseArg || (opt.prefix !== null && !/^\/[A-Za-z0-9_.~-]+$/.test(opt.prefix ?? ''))) {
  console.error('usage: node docs_check.mjs BASE_URL [--behind-prefix /PREFIX] [--resolve HOST] [--shots DIR] [--chromium PATH]');
  process.exit(2);
}
const service = new URL(baseArg.replace(/\/+$/, '') + '/');

// A path-prefix reverse proxy, in this process: PREFIX/x → service/x.
let proxy = null;
if (opt.prefix) {
  proxy = http.createServer((req, res) => {
    if (!req.url.startsWith(`${opt.prefix}/`)) {
      res.writeHead(404, { 'content-type': 'text/plain' });
      res.end(`outside ${opt.prefix}/\n`);
      return;
    }
    const upstream = http.request({
      host: service.hostname, port: service.port, method: req.method,
      path: req.url.slice(opt.prefix.length), headers: { ...req.headers, host: service.host },
    }, (up) => { res.writeHead(up.statusCode, up.headers); up.pipe(res); });
    upstream.on('error', (e) => { res.writeHead(502, { 'content-type': 'text/plain' }); res.end(`${e}\n`); });
    req.pipe(upstream);
  });
  await new Promise((ok) => proxy.listen(0, '127.0.0.1', ok));
}
const host = opt.resolve ?? service.hostname;
const port = proxy ? proxy.address().port : service.port;
const base = new URL(`${service.protocol}//${host}${port ? `:${port}` : ''}${opt.prefix ?? ''}/`);
const prefix = base.pathname;                              // '/' or '/ilqr/'
const at = (p) => new URL(p, base).href;                   // at('docs') → …/ilqr/docs
const label = `${opt.prefix ? opt.prefix.slice(1) : 'direct'}${opt.resolve ? `-${opt.resolve}` : ''}`;
const shotsDir = opt.shots ?? mkdtempSync(path.join(os.tmpdir(), 'docs-check-shots-'));
mkdirSync(shotsDir, { recursive: true });

// ---- reporting ----
const results = [];
function check(name, ok, detail = '') {
  results.push({ name, ok: !!ok, detail });
  console.log(`${ok ? 'PASS' : 'FAIL'}  ${name}${detail ? ` — ${detail}` : ''}`);
  return !!ok;
}
const info = (msg) => console.log(`INFO  ${msg}`);
let shotN = 0;
async function shot(page, name, fullPage = true) {
  const file = path.join(shotsDir, `${label}-${String(++shotN).padStart(2, '0')}-${name}.png`);
  await page.screenshot({ path: file, fullPage });
  info(`screenshot ${file}`);
  return file;
}

// ---- browser ----
const started = Date.now();
const userDataDir = mkdtempSync(path.join(os.tmpdir(), 'docs-check-profile-'));
// playwright-core adds --headless (headless: true) and --user-data-dir (the
// fresh profile passed to launchPersistentContext) itself.
const args = [
  '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
  '--disable-background-networking', '--disable-component-update', '--disable-sync',
];
if (opt.resolve) {
  // Only HOST resolves (to loopback); every other name fails without DNS.
  args.push(`--host-resolver-rules=MAP ${opt.resolve} 127.0.0.1, MAP * ~NOTFOUND, EXCLUDE 127.0.0.1, EXCLUDE localhost`);
}
const context = await chromium.launchPersistentContext(userDataDir, {
  executablePath: opt.chromium, headless: true, args,
  viewport: { width: 1280, height: 900 }, acceptDownloads: true,
});
const page = context.pages()[0] ?? await context.newPage();
page.setDefaultTimeout(15000);

const requests = [];        // every request: {method, url, type, status, phase}
const consoleMsgs = [];     // {type, text, phase}
let phase = 'load';
const foreign = (u) => {
  const url = new URL(u);
  if (url.protocol === 'data:' || url.protocol === 'blob:') return false;
  return url.origin !== base.origin;
};
await context.route('**/*', (route) => {
  const u = route.request().url();
  if (/^(data|blob):/.test(u)) return route.continue();
  if (foreign(u)) return route.abort('blockedbyclient');
  return route.continue();
});
context.on('request', (r) => {
  requests.push({ req: r, method: r.method(), url: r.url(), type: r.resourceType(), status: null, phase, failure: null });
});
context.on('response', (res) => {
  const e = requests.find((x) => x.req === res.request());
  if (e) e.status = res.status();
});
context.on('requestfailed', (r) => {
  const e = requests.find((x) => x.req === r);
  if (e) e.failure = r.failure()?.errorText || 'failed';
});
page.on('console', (m) => consoleMsgs.push({ type: m.type(), text: m.text(), phase, loc: m.location()?.url }));
page.on('pageerror', (err) => consoleMsgs.push({ type: 'pageerror', text: String(err), phase }));

// Node-side GET for references (not part of the page's traffic), sent to
// 127.0.0.1 whatever the URL's host name (which --resolve may have made up).
function getJson(u) {
  const url = new URL(u);
  return new Promise((resolve) => {
    http.get({ host: '127.0.0.1', port: url.port, path: url.pathname, headers: { host: url.host } }, (res) => {
      let data = '';
      res.setEncoding('utf8');
      res.on('data', (c) => { data += c; });
      res.on('end', () => {
        let body = null; try { body = JSON.parse(data); } catch { /* not JSON */ }
        resolve({ status: res.statusCode, type: res.headers['content-type'], body });
      });
    }).on('error', (e) => resolve({ status: `error ${e.message}`, type: null, body: null }));
  });
}

const deepEqual = (a, b) => JSON.stringify(sortKeys(a)) === JSON.stringify(sortKeys(b));
function sortKeys(v) {
  if (Array.isArray(v)) return v.map(sortKeys);
  if (v && typeof v === 'object') return Object.fromEntries(Object.keys(v).sort().map((k) => [k, sortKeys(v[k])]));
  return v;
}

// Executes the currently expanded POST /solve with `body` and returns what
// the UI shows plus the network exchange it made.
async function execute(op, body, name) {
  phase = `execute:${name}`;
  const textarea = op.locator('textarea.body-param__text');
  await textarea.fill(body);
  const before = requests.length;
  const respPromise = page.waitForResponse((r) => r.request().method() === 'POST' && new URL(r.url()).pathname.endsWith('/solve'), { timeout: 30000 }).catch(() => null);
  await op.locator('button.execute').click();
  const res = await respPromise;
  // Wait for the UI to render the live response (or an inline validation error).
  await page.waitForTimeout(300);
  await op.locator('.live-responses-table, .validation-errors, .errors-wrapper').first().waitFor({ timeout: 10000 }).catch(() => {});
  const ui = await op.evaluate((el) => {
    const t = (s) => el.querySelector(s)?.innerText?.trim() ?? null;
    const live = el.querySelector('.live-responses-table');
    return {
      requestUrl: t('.request-url pre') ?? t('.request-url'),
      curl: t('.curl-command .curl, .curl'),
      status: live ? live.querySelector('tbody .response-col_status')?.innerText?.trim() : null,
      body: live ? (live.querySelector('.response-col_description .microlight, .response-col_description pre')?.innerText ?? null) : null,
      headers: live ? (live.querySelector('.response-col_description .response-headers, .response-col_description pre.microlight ~ * pre')?.innerText ?? null) : null,
      allText: live ? live.innerText : null,
      validation: el.querySelector('.validation-errors, .errors')?.innerText ?? null,
      textareaInvalid: !!el.querySelector('textarea.body-param__text.invalid'),
    };
  });
  const net = res ? {
    url: res.url(), status: res.status(),
    contentType: res.headers()['content-type'] || null,
    reqContentType: res.request().headers()['content-type'] || null,
    body: await res.text().catch(() => null),
  } : null;
  const newReqs = requests.slice(before).map((r) => `${r.method} ${r.url}`);
  return { ui, net, newReqs };
}

try {
  // ---------------- 1. /docs loads, redirects, renders ----------------
  info(`base ${base.href} (label ${label}); chromium ${context.browser()?.version() ?? '?'}`);
  const spec = await getJson(at('openapi.json'));
  check('GET openapi.json (node) is 200 JSON', spec.status === 200 && spec.body, `status ${spec.status}`);
  const seed = await getJson(at('problems/default'));
  check('GET problems/default (node) is 200 JSON', seed.status === 200 && seed.body, `status ${seed.status}`);

  const docsUrl = at('docs');
  const nav = await page.goto(docsUrl, { waitUntil: 'networkidle', timeout: 60000 });
  const chain = [];
  for (let r = nav?.request(); r; r = r.redirectedFrom()) chain.unshift(r);
  for (const r of chain) {
    const resp = await r.response();
    info(`navigation ${r.url()} → ${resp?.status()}${resp?.headers().location ? ` Location: ${resp.headers().location}` : ''}`);
  }
  const first = chain[0] ? await chain[0].response() : null;
  check('/docs answers with a redirect', first && first.status() >= 300 && first.status() < 400,
    `status ${first?.status()}, Location ${first?.headers().location}`);
  check('redirect lands on docs/ under the base', page.url() === at('docs/'), `final URL ${page.url()}`);
  check('docs/ page is 200', nav?.status() === 200, `status ${nav?.status()}`);
  await page.locator('.swagger-ui .info .title').waitFor({ timeout: 20000 }).catch(() => {});
  await page.locator('.opblock').first().waitFor({ timeout: 20000 }).catch(() => {});
  await page.waitForLoadState('networkidle');
  await shot(page, 'loaded');

  const title = await page.title();
  const infoTitle = (await page.locator('.swagger-ui .info .title').first().innerText().catch(() => '')).trim();
  info(`document title: ${JSON.stringify(title)}; info title: ${JSON.stringify(infoTitle)}`);
  check('Swagger UI rendered the spec (info title names ilqr-service)', infoTitle.includes('ilqr-service'), infoTitle);
  check('the browser tab names the service', title === 'ilqr-service API', JSON.stringify(title));
  const loadErr = await page.locator('.swagger-ui .errors-wrapper, .swagger-ui .loading-container .errors').allInnerTexts();
  check('no spec-load error box', loadErr.length === 0, loadErr.join(' | ').slice(0, 300));

  // ---------------- 2. operations ----------------
  const ops = await page.$$eval('.opblock', (els) => els.map((e) => {
    const m = e.querySelector('.opblock-summary-method')?.innerText.trim();
    const p = e.querySelector('.opblock-summary-path')?.getAttribute('data-path') || e.querySelector('.opblock-summary-path')?.innerText.trim();
    return `${m} ${p}`;
  }));
  info(`operations listed: ${ops.join(', ')}`);
  for (const want of ['POST /solve', 'GET /problems/default', 'GET /healthz', 'GET /readyz', 'GET /metrics', 'GET /openapi.json']) {
    check(`operation ${want} listed`, ops.includes(want));
  }
  const servers = await page.$$eval('.servers select option', (os) => os.map((o) => o.value)).catch(() => []);
  info(`servers dropdown: ${JSON.stringify(servers)}`);

  const op = page.locator('.opblock-post', { has: page.locator('[data-path="/solve"]') }).first();
  await op.locator('.opblock-summary').first().click();
  await op.locator('.opblock-body').waitFor({ timeout: 10000 });
  await page.waitForTimeout(300);
  const exampleText = await op.locator('.opblock-section-request-body .body-param__example, .opblock-section-request-body .highlight-code .microlight, .opblock-section-request-body pre').first().innerText().catch(() => null);
  let example = null;
  try { example = JSON.parse(exampleText); } catch { /* below */ }
  check('POST /solve shows a JSON example body', example !== null, exampleText ? `${exampleText.length} chars` : 'no example found');
  if (example && seed.body) {
    const same = deepEqual(example, seed.body);
    let diff = '';
    if (!same) {
      const keys = new Set([...Object.keys(example), ...Object.keys(seed.body)]);
      diff = [...keys].filter((k) => JSON.stringify(sortKeys(example[k])) !== JSON.stringify(sortKeys(seed.body[k])))
        .map((k) => `${k}: example ${JSON.stringify(example[k])} vs default ${JSON.stringify(seed.body[k])}`).join('; ');
    }
    check('example body equals GET problems/default (the seed problem)', same, diff);
  }
  await op.locator('.opblock-section-request-body').scrollIntoViewIfNeeded().catch(() => {});
  await shot(page, 'solve-expanded', false);

  await op.locator('button.try-out__btn').click();
  await op.locator('textarea.body-param__text').waitFor({ timeout: 10000 });
  const ok = await execute(op, exampleText ?? '{}', 'example');
  info(`UI request URL: ${ok.ui.requestUrl}`);
  info(`network: ${ok.net ? `${ok.net.status} ${ok.net.url} (${ok.net.contentType})` : 'no POST seen'}`);
  check('Execute (example body) POSTs to <base>/solve', ok.net && ok.net.url === at('solve'), ok.net?.url);
  check('UI shows the same request URL', ok.ui.requestUrl === at('solve'), ok.ui.requestUrl);
  let okBody = null;
  try { okBody = JSON.parse(ok.net?.body ?? ''); } catch { /* below */ }
  check('response 200 with status "converged"', ok.net?.status === 200 && okBody?.status === 'converged',
    `HTTP ${ok.net?.status}, UI status ${ok.ui.status}, body status ${okBody?.status}, iterations ${okBody?.iterations}, cost ${okBody?.cost}`);
  check('UI shows 200', ok.ui.status === '200', ok.ui.status);
  await op.locator('.live-responses-table').scrollIntoViewIfNeeded().catch(() => {});
  await shot(page, 'execute-200', false);

  // Response "Download" button (Swagger UI's download of the response body).
  const dl = op.locator('.live-responses-table .download-contents').first();
  if (await dl.count()) {
    const [download] = await Promise.all([page.waitForEvent('download', { timeout: 10000 }).catch(() => null), dl.click()]);
    let dlOk = false, detail = 'no download event';
    if (download) {
      const p = await download.path().catch(() => null);
      const text = p ? await readFile(p, 'utf8').catch(() => '') : '';
      let parsed = null; try { parsed = JSON.parse(text); } catch { /* */ }
      dlOk = parsed?.status === 'converged';
      detail = `file ${download.suggestedFilename()}, ${text.length} bytes, JSON status ${parsed?.status}`;
    }
    check('response "Download" button saves the result JSON', dlOk, detail);
  } else {
    check('response "Download" button present', false, 'no .download-contents');
  }

  // ---------------- 3. error bodies ----------------
  const bad = await execute(op, '{"dt": -1}', 'dt-1');
  let badBody = null;
  try { badBody = JSON.parse(bad.net?.body ?? ''); } catch { /* */ }
  info(`{"dt": -1}: ${bad.net?.status} ${bad.net?.contentType} ${bad.net?.body?.slice(0, 400)}`);
  info(`{"dt": -1} UI: status ${bad.ui.status}; shown body ${JSON.stringify(bad.ui.body?.slice(0, 400))}`);
  check('{"dt": -1} → 422 application/problem+json', bad.net?.status === 422 && /application\/problem\+json/.test(bad.net?.contentType ?? ''),
    `${bad.net?.status} ${bad.net?.contentType}`);
  check('422 names the field (/dt)', JSON.stringify(badBody ?? {}).includes('/dt') || JSON.stringify(badBody ?? {}).includes('"dt"'),
    JSON.stringify(badBody?.errors ?? badBody)?.slice(0, 300));
  check('UI shows 422 and the problem document', bad.ui.status === '422' && (bad.ui.body ?? '').includes('dt'), `UI status ${bad.ui.status}`);
  await op.locator('.live-responses-table').scrollIntoViewIfNeeded().catch(() => {});
  await shot(page, 'execute-422', false);

  const broken = await execute(op, '{not json', 'not-json');
  info(`{not json: network ${broken.net ? `${broken.net.status} ${broken.net.contentType} ${broken.net.body?.slice(0, 300)}` : 'no request sent'}`);
  info(`{not json UI: status ${broken.ui.status}; validation ${JSON.stringify(broken.ui.validation)}; textarea marked invalid ${broken.ui.textareaInvalid}; body ${JSON.stringify(broken.ui.body?.slice(0, 300))}`);
  check('{not json → 400 application/problem+json', broken.net?.status === 400 && /application\/problem\+json/.test(broken.net?.contentType ?? ''),
    broken.net ? `${broken.net.status} ${broken.net.contentType}` : 'the UI sent no request');
  check('UI shows 400', broken.ui.status === '400', `UI status ${broken.ui.status}`);
  await op.locator('.live-responses-table').first().scrollIntoViewIfNeeded().catch(() => {});
  await shot(page, 'execute-400', false);
  phase = 'after';

  // ---------------- every GET operation through Try it out ----------------
  for (const p of ['/problems/default', '/healthz', '/readyz', '/metrics', '/openapi.json', '/docs/']) {
    phase = `get:${p}`;
    const g = page.locator('.opblock-get', { has: page.locator(`[data-path="${p}"]`) }).first();
    if (!(await g.count())) { check(`GET ${p}: operation present`, false); continue; }
    await g.locator('.opblock-summary').first().click();
    await g.locator('button.try-out__btn').click();
    const wait = page.waitForResponse((r) => r.request().method() === 'GET' && new URL(r.url()).pathname.endsWith(p), { timeout: 15000 }).catch(() => null);
    await g.locator('button.execute').click();
    const r = await wait;
    await g.locator('.live-responses-table').waitFor({ timeout: 10000 }).catch(() => {});
    const uiUrl = (await g.locator('.request-url pre').first().innerText().catch(() => '')).trim();
    const uiStatus = (await g.locator('.live-responses-table tbody .response-col_status').first().innerText().catch(() => '')).trim();
    check(`GET ${p} via Try it out → 200 at <base>${p.slice(1)}`, r?.status() === 200 && r?.url() === at(p.slice(1)) && uiUrl === at(p.slice(1)) && uiStatus === '200',
      `${r?.url()} → ${r?.status()}; UI shows ${uiUrl} ${uiStatus}`);
    await g.locator('.opblock-summary').first().click();   // collapse again
  }
  phase = 'after';

  // ---------------- 5. spec link, Explore, schemas ----------------
  const link = await page.$eval('.info a.link, .info .url', (a) => ({ text: a.innerText.trim(), href: a.closest('a')?.href ?? null })).catch(() => null);
  info(`spec link in the header: text ${JSON.stringify(link?.text)} href ${link?.href}`);
  if (link?.href) {
    // Click it as a user would: it opens the spec in a new tab.
    phase = 'spec-link';
    const [popup] = await Promise.all([context.waitForEvent('page'), page.locator('.info a.link').first().click()]);
    popup.on('console', (m) => consoleMsgs.push({ type: m.type(), text: m.text(), phase, loc: m.location()?.url }));
    await popup.waitForLoadState();
    const nav = requests.find((r) => r.phase === 'spec-link' && r.type === 'document' && r.url === popup.url());
    const popupResp = nav ? { status: () => nav.status } : null;
    let body = null;
    try { body = JSON.parse(await popup.evaluate(() => document.body.innerText)); } catch { /* not JSON */ }
    check('header spec link opens the served spec', popup.url() === at('openapi.json') && popupResp?.status() === 200 && body?.openapi,
      `${popup.url()} → ${popupResp?.status()}, openapi ${body?.openapi}`);
    await popup.close();
    phase = 'after';
  } else {
    check('header spec link present', false);
  }
  const dlInput = await page.$eval('.topbar .download-url-input', (i) => i.value).catch(() => null);
  info(`topbar URL field: ${JSON.stringify(dlInput)}`);
  if (dlInput !== null) {
    phase = 'explore';
    const wait = page.waitForResponse((r) => r.url().endsWith('openapi.json'), { timeout: 10000 }).catch(() => null);
    await page.locator('.topbar .download-url-button').click();
    const r = await wait;
    await page.locator('.opblock').first().waitFor({ timeout: 10000 }).catch(() => {});
    const nOps = await page.locator('.opblock').count();
    check('topbar "Explore" reloads the spec', r && r.status() === 200 && r.url() === at('openapi.json') && nOps >= 6,
      `${r?.url()} → ${r?.status()}, ${nOps} operations`);
    phase = 'after';
  }

  // Schemas: ProblemSpec shows field docs with units. OAS 3.1 specs render
  // with Swagger UI's JSON Schema 2020-12 components: a property's
  // description shows once it is expanded ("Expand all").
  const models = page.locator('section.models');
  if (await models.count()) {
    if (!((await models.getAttribute('class')) ?? '').includes('is-open')) await models.locator('h4').first().click();
    const ps = models.locator('article[data-json-schema-level="0"]', {
      has: page.locator(':scope > .json-schema-2020-12-head .json-schema-2020-12__title', { hasText: /^ProblemSpec$/ }),
    });
    check('Schemas: ProblemSpec listed', (await ps.count()) === 1);
    await ps.locator('.json-schema-2020-12-expand-deep-button').first().click();
    await page.waitForTimeout(500);
    const text = await ps.innerText();
    const props = spec.body?.components?.schemas?.ProblemSpec?.properties ?? {};
    const missing = Object.entries(props).filter(([, v]) => v.description && !text.includes(v.description.split('\n')[0]))
      .map(([k]) => k);
    check('Schemas: every ProblemSpec field shows its description', missing.length === 0 && Object.keys(props).length > 0,
      missing.length ? `missing: ${missing.join(', ')}` : `${Object.keys(props).length} fields`);
    check('Schemas: units shown (dt "in seconds", initial_state "m/s", model.gravity "m/s²")',
      text.includes('Time step in seconds') && text.includes('m/s, m/s, rad/s') && text.includes('m/s²'));
    await ps.scrollIntoViewIfNeeded();
    await shot(page, 'schema-problemspec', false);
  } else {
    check('Schemas section present', false);
  }
  await page.waitForLoadState('networkidle').catch(() => {});
  await shot(page, 'final');
} catch (e) {
  check('check ran to the end', false, String(e?.stack || e));
  await shot(page, 'exception').catch(() => {});
}

// ---------------- network + console summary ----------------
console.log(`\nRequests the page made (${requests.length}):`);
for (const r of requests) {
  console.log(`  [${r.phase}] ${r.method} ${r.url} (${r.type}) → ${r.status ?? r.failure ?? '?'}`);
}
const offOrigin = requests.filter((r) => foreign(r.url));
check('no request to another origin', offOrigin.length === 0, offOrigin.map((r) => r.url).join(', '));
const outside = requests.filter((r) => !foreign(r.url) && !/^(data|blob):/.test(r.url) && !new URL(r.url).pathname.startsWith(prefix));
check(`every request stays under ${prefix}`, outside.length === 0, outside.map((r) => r.url).join(', '));
// 4xx/5xx are expected only for the deliberate error executes.
const badStatus = requests.filter((r) => r.status >= 400 && !(r.phase.startsWith('execute:') && r.phase !== 'execute:example' && r.method === 'POST'));
check('no 4xx/5xx for any asset or spec request', badStatus.length === 0, badStatus.map((r) => `${r.url} → ${r.status}`).join(', '));
const failed = requests.filter((r) => r.failure && !foreign(r.url));
check('no failed request (same origin)', failed.length === 0, failed.map((r) => `${r.url}: ${r.failure}`).join(', '));
console.log(`\nConsole messages (${consoleMsgs.length}):`);
for (const m of consoleMsgs) console.log(`  [${m.phase}] ${m.type}: ${m.text}${m.loc ? ` (${m.loc})` : ''}`);
// The browser logs every 4xx fetch as a console error; those of the deliberate
// error executes are expected.
const errs = consoleMsgs.filter((m) => (m.type === 'error' || m.type === 'pageerror')
  && !(m.phase.startsWith('execute:') && m.phase !== 'execute:example' && /status of 4\d\d/.test(m.text)));
check('no console errors (besides the deliberate 4xx)', errs.length === 0, errs.map((m) => m.text).join(' | ').slice(0, 500));

await context.close();
if (proxy) proxy.close();
await rm(userDataDir, { recursive: true, force: true });
console.log(`screenshots: ${shotsDir}`);
const failedChecks = results.filter((r) => !r.ok);
console.log(`\n${results.length - failedChecks.length} passed, ${failedChecks.length} failed (${((Date.now() - started) / 1000).toFixed(1)} s, ${base.href})`);
process.exit(failedChecks.length ? 1 : 0);
