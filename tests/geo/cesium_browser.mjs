// Loads a terrain tileset in CesiumJS running in headless Chromium: a page served from a
// local HTTP server (127.0.0.1) loads CesiumJS's browser build (npm `cesium`,
// Build/Cesium/Cesium.js, its web workers decoding the tiles), opens the tileset with
// CesiumTerrainProvider (tiles gzip-encoded, as a Cesium server delivers them), samples it
// with sampleTerrainMostDetailed and posts the heights back to the server.
// Usage: node cesium_browser.mjs CHROMIUM NODE_MODULES_DIR TERRAIN_DIR POINTS_JSON
// POINTS_JSON: [[lon, lat], ...] in degrees; prints {"heights": [...], ...} in metres.
import { spawn } from 'node:child_process'
import fs from 'node:fs'
import os from 'node:os'
import path from 'node:path'
import { serve } from './serve_terrain.mjs'

const [chromium, modules, dir, pointsFile] = process.argv.slice(2)
const PAGE = `<!doctype html>
<html><head><meta charset="utf-8">
<script>window.CESIUM_BASE_URL = '/cesium/'</script>
<script src="/cesium/Cesium.js"></script></head>
<body><script>
const report = (r) => fetch('/result', { method: 'POST', body: JSON.stringify(r) })
;(async () => {
  const provider = await Cesium.CesiumTerrainProvider.fromUrl('/terrain/', { requestVertexNormals: true })
  const pts = (await (await fetch('/points.json')).json())
    .map(([lon, lat]) => Cesium.Cartographic.fromDegrees(lon, lat))
  const out = await Cesium.sampleTerrainMostDetailed(provider, pts, true)
  await report({
    hasVertexNormals: provider.hasVertexNormals,
    heights: out.map((p) => p.height),
    cesium: Cesium.VERSION,
    userAgent: navigator.userAgent
  })
})().catch((e) => report({ error: String((e && e.stack) || e) }))
</script></body></html>`

let done
const result = new Promise((resolve) => { done = resolve })
const { server, url } = await serve(
  { '/cesium/': path.join(modules, 'cesium/Build/Cesium'), '/terrain/': dir },
  (req, res) => {
    if (req.url === '/' || req.url === '/points.json') {
      res.writeHead(200, { 'Content-Type': req.url === '/' ? 'text/html' : 'application/json' })
      res.end(req.url === '/' ? PAGE : fs.readFileSync(pointsFile))
      return true
    }
    if (req.url === '/result' && req.method === 'POST') {
      let body = ''
      req.on('data', (c) => { body += c })
      req.on('end', () => { res.end(); done(JSON.parse(body)) })
      return true
    }
    return false
  })
// The flags a sandbox without network needs (no background connections, no sandbox as
// root), and a fresh profile.
const profile = fs.mkdtempSync(path.join(os.tmpdir(), 'terratile-chromium-'))
const browser = spawn(chromium, [
  '--headless', '--no-sandbox', '--disable-gpu', '--disable-quic', '--no-first-run',
  '--disable-background-networking', '--disable-component-update', '--disable-sync',
  `--user-data-dir=${profile}`, url
], { stdio: ['ignore', 'ignore', 'pipe'], detached: true })
let stderr = ''
browser.stderr.on('data', (c) => { stderr += c })
const exited = new Promise((resolve) => browser.on('exit', (code) => resolve({ exited: code })))
let timer
const timeout = new Promise((resolve) => { timer = setTimeout(() => resolve({ timeout: true }), 120000) })
try {
  const r = await Promise.race([result, exited, timeout])
  if (r.heights === undefined) {
    process.stderr.write(`${JSON.stringify(r)}\n${stderr}`)
    process.exitCode = 1
  } else {
    process.stdout.write(JSON.stringify(r))
  }
} finally {
  clearTimeout(timer)
  // The browser and the helper processes it started (its own process group).
  try { process.kill(-browser.pid, 'SIGKILL') } catch {}
  server.close()
  await new Promise((resolve) => setTimeout(resolve, 200))
  try { fs.rmSync(profile, { recursive: true, force: true }) } catch {}
}
