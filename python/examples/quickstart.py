import numpy as np, volrad
z, y, x = np.mgrid[0:32, 0:48, 0:48] + 0.5  # cell centres; arrays are (nz, ny, nx)
r = np.sqrt(((x - 24) / 20) ** 2 + ((y - 24) / 20) ** 2 + ((z - 14) / 11) ** 2)
sigma_t = 1.2 * np.clip(1 - r, 0, None) * np.random.default_rng(7).uniform(0.5, 1.5, r.shape)
scene = volrad.Scene(sigma_t, albedo=0.99, phase={"kind": "henyey-greenstein", "g": 0.6},
                     lights=[{"kind": "sky", "sun_elevation_degrees": 35, "sun_azimuth_degrees": 150}],
                     method="discrete-ordinates", interpolation="trilinear")
solution = scene.solve(progress=True)
image = solution.render(eye=[24, -60, 10], target=[24, 24, 16], up=[0, 0, 1], width=480, height=320)
volrad.write_image(image, "blob.png")  # (H, W, 3) float32 radiance, tone-mapped like the CLI's
