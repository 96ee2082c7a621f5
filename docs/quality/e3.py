from lib import *
import dataclasses, sys
SS = 3
def ss_img(sc, cam, t):
    big = Camera(cam.view, cam.proj, cam.width*SS, cam.height*SS)
    g = sc.ground_truth(big, t, samples=1).astype(np.float64)
    return np.round(g.reshape(cam.height, SS, cam.width, SS, 3).mean((1, 3))).astype(np.uint8)
name, scale = "courtyard", 0.125
for variant, delay in (("dynamic", 0.1), ("static", 0.0)):
    sc = scene(name, variant)
    fr = server_frames(name, variant, scale, delay)
    cams, truth = gt(name, variant, scale, delay=delay)
    fr2 = [dataclasses.replace(f, main=dataclasses.replace(f.main, color=ss_img(sc, f.main.camera, f.time)),
                               aux=tuple(dataclasses.replace(a, color=ss_img(sc, a.camera, f.time)) for a in f.aux)) for f in fr]
    truth2 = [ss_img(sc, c, n / FC) for n, c in enumerate(cams)]
    res = run(fr2, cams)
    sm = score(res.images, truth2, use_vmaf=True)
    print(variant, delay, f"ours, {SS}x{SS} supersampled colour + GT", {k: round(v, 4) for k, v in sm.mean.items()}, flush=True)
    if variant == "dynamic":
        import pickle; pickle.dump(dict(imgs=res.images, truth=truth2), open("ss.pkl", "wb"))
# sub-pixel floor: static scene, client camera = server camera shifted by half a pixel, alpha = 0
sc = scene(name, "static"); fr = server_frames(name, "static", scale, 0.0, n=2)
cam = fr[0].main.camera
for dx in (0.25, 0.5, 1.0):
    P = np.array(cam.proj); S = np.eye(4); S[0, 3] = 2 * dx / cam.width  # NDC shift of dx pixels
    c2 = Camera(cam.view, S @ P, cam.width, cam.height)
    out = reproject_alpha(fr[0], fr[1], c2, 0.0, "ours")
    g = sc.ground_truth(c2, 0.0, samples=1)
    print(f"static, alpha=0, camera shifted {dx} px: ours vs GT psnr {psnr(out, g):.2f} ssim {ssim(out, g):.4f}", flush=True)
