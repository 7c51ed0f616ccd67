// Loads a terrain tileset with CesiumJS's own CesiumTerrainProvider (npm @cesium/engine,
// under Node: no browser) from a local HTTP server that serves the tiles as a Cesium server
// does (gzip content encoding), and samples it with sampleTerrainMostDetailed.
// Usage: node cesium_sample.mjs NODE_MODULES_DIR TERRAIN_DIR POINTS_JSON
// POINTS_JSON: [[lon, lat], ...] in degrees; prints [height, ...] in metres.
import { createRequire } from 'node:module'
import fs from 'node:fs'
import path from 'node:path'
import { pathToFileURL } from 'node:url'
import { serve } from './serve_terrain.mjs'

const [modules, dir, pointsFile] = process.argv.slice(2)
const require = createRequire(path.join(modules, 'x.js'))
const Cesium = await import(pathToFileURL(require.resolve('@cesium/engine')).href)
const { server, url } = await serve({ '/': dir })
try {
  const provider = await Cesium.CesiumTerrainProvider.fromUrl(url, { requestVertexNormals: true })
  const pts = JSON.parse(fs.readFileSync(pointsFile, 'utf8'))
    .map(([lon, lat]) => Cesium.Cartographic.fromDegrees(lon, lat))
  const out = await Cesium.sampleTerrainMostDetailed(provider, pts, true)
  process.stdout.write(JSON.stringify({
    hasVertexNormals: provider.hasVertexNormals,
    heights: out.map((p) => p.height)
  }))
} finally {
  server.close()
}
