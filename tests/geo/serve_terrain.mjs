// A local HTTP server (127.0.0.1, a free port) that serves files as a Cesium terrain server
// does: `.terrain` tiles gzip-encoded (they are stored gzipped), JSON as JSON. `routes` maps a
// URL path prefix to a directory (longest prefix first); `extra(req, res)` may answer a
// request first (returning true). Used by cesium_sample.mjs (Node) and cesium_browser.mjs.
import http from 'node:http'
import fs from 'node:fs'
import path from 'node:path'

const TYPES = {
  '.terrain': { 'Content-Type': 'application/vnd.quantized-mesh', 'Content-Encoding': 'gzip' },
  '.json': { 'Content-Type': 'application/json' },
  '.js': { 'Content-Type': 'text/javascript' },
  '.html': { 'Content-Type': 'text/html' },
  '.css': { 'Content-Type': 'text/css' },
  '.wasm': { 'Content-Type': 'application/wasm' }
}

export async function serve (routes, extra = () => false) {
  const prefixes = Object.keys(routes).sort((a, b) => b.length - a.length)
  const server = http.createServer((req, res) => {
    if (extra(req, res)) return
    const url = decodeURIComponent(new URL(req.url, 'http://x').pathname)
    const prefix = prefixes.find((p) => url.startsWith(p))
    const dir = prefix === undefined ? undefined : path.resolve(routes[prefix])
    const p = dir && path.join(dir, url.slice(prefix.length))
    if (!p || !p.startsWith(dir) || !fs.existsSync(p) || fs.statSync(p).isDirectory()) {
      res.writeHead(404)
      res.end()
      return
    }
    res.writeHead(200, TYPES[path.extname(p)] ?? { 'Content-Type': 'application/octet-stream' })
    res.end(fs.readFileSync(p))
  })
  await new Promise((resolve) => server.listen(0, '127.0.0.1', resolve))
  return { server, url: `http://127.0.0.1:${server.address().port}/` }
}
