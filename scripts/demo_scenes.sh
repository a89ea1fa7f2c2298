# The demo's scenes (scripts/demo.sh), sourced by it and by the benchmarks that render them:
# particles2vdb, vdbcache light and camera flags per scene.

# A flat cumulus deck (340 x 360 x 40 units) under a low sun, seen from above its edge.
CLOUD_DENSITY="--voxel-size 2"
CLOUD_LIGHT="--extinction 30 --albedo 0.95 --g 0.6 --sun dir=0.5,0.3,-0.8,irradiance=4 --sky 0.12,0.2,0.36"
CLOUD_CAMERA="--eye 170,-300,160 --look-at 170,180,10"
# A smoke plume rising 150 units, darker and more absorbing, lit from the side.
PLUME_DENSITY="--voxel-size 1"
PLUME_LIGHT="--extinction 40 --albedo 0.8 --g 0.3 --sun dir=-0.7,0.5,-0.5,irradiance=5 --sky 0.15,0.24,0.42"
PLUME_CAMERA=""
