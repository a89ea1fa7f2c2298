# The demo's scenes (scripts/demo.sh), sourced by it and by the benchmarks that render them:
# particles2vdb, vdbcache light and camera flags per scene.

# A cumulus (data/cumulus.ply: 120,000 particles, a cauliflower of puffs on a flat base,
# about 300 x 200 x 200 units) under a low sun from the camera's left and behind it, a blue
# sky, seen from -Y: a sunlit left side, the tower's shadow over the right of its foot.
CUMULUS_DENSITY="--voxel-size 2"
CUMULUS_LIGHT="--extinction 0.25 --albedo 0.9 --g 0.45 --sun dir=0.7,-0.3,-0.55,irradiance=8 --sky 0.08,0.14,0.3"
CUMULUS_CAMERA="--eye 0,-700,70 --look-at 0,0,95"
# A flat cumulus deck (340 x 360 x 40 units) under a low sun, seen from above its edge.
CLOUD_DENSITY="--voxel-size 2"
CLOUD_LIGHT="--extinction 30 --albedo 0.95 --g 0.6 --sun dir=0.5,0.3,-0.8,irradiance=4 --sky 0.12,0.2,0.36"
CLOUD_CAMERA="--eye 170,-300,160 --look-at 170,180,10"
# A smoke plume rising 150 units, darker and more absorbing, lit from the side.
PLUME_DENSITY="--voxel-size 1"
PLUME_LIGHT="--extinction 40 --albedo 0.8 --g 0.3 --sun dir=-0.7,0.5,-0.5,irradiance=5 --sky 0.15,0.24,0.42"
PLUME_CAMERA=""
