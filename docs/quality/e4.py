from lib import *
import dataclasses
SS = 3
def ss_img(sc, cam, t):
    big = Camera(cam.view, cam.proj, cam.width*SS, cam.height*SS)
    g = sc.ground_truth(big, t, samples=1).astype(np.float64)
    return np.round(g.reshape(cam.height, SS, cam.width, SS, 3).mean((1, 3))).astype(np.uint8)
name, scale, variant, delay = "courtyard", 0.125, "dynamic", 0.1
sc = scene(name, variant)
fr = server_frames(name, variant, scale, delay)
cams, truth = gt(name, variant, scale, delay=delay)
truth2 = [ss_img(sc, c, n / FC) for n, c in enumerate(cams)]
res = run(fr, cams)
sm = score(res.images, truth2, use_vmaf=True)
print("point-sampled server, 3x3 GT", {k: round(v, 4) for k, v in sm.mean.items()}, flush=True)
