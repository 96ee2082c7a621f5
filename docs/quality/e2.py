from lib import *
import pickle, sys
name = sys.argv[1]; scale = float(sys.argv[2]); vm = len(sys.argv) > 3
rows = []
def rec(label, imgs, truth, info=None):
    sm = score(imgs, truth, use_vmaf=vm)
    r = dict(label=label, **{k: round(v, 4) for k, v in sm.mean.items()})
    if info is not None:
        al = np.array([i.alpha for i in info])[12:108]
        ps = np.array([f["psnr"] for f in sm.per_frame])
        lo = ps[np.abs(al - np.round(al)) < 0.15].mean(); hi = ps[np.abs(al - np.round(al)) > 0.35].mean()
        r.update(psnr_alpha_near_int=round(lo, 2), psnr_alpha_mid=round(hi, 2))
    rows.append(r); print(r, flush=True)
    return sm
t0 = time.time()
for variant in ("dynamic", "static"):
    for delay in (0.1, 0.0):
        fr = server_frames(name, variant, scale, delay)
        cams, truth = gt(name, variant, scale, delay=delay)
        res = run(fr, cams)
        tag = f"{variant} delay={delay}"
        rec(f"{tag} ours", res.images, truth, res.info)
        if variant == "dynamic" and delay == 0.1:
            pickle.dump(dict(imgs=res.images, truth=truth, info=res.info), open(f"base_{name}_{scale}.pkl", "wb"))
            rec(f"{tag} ours use_shadows=False", run(fr, cams, use_shadows=False).images, truth)
            rec(f"{tag} ours use_aux=False", run(fr, cams, use_aux=False).images, truth)
            rec(f"{tag} ours_extrapolate", run(fr, cams, "ours_extrapolate").images, truth)
            for toff in (-1/FC, -0.5/FC, 0.5/FC, 1/FC):
                _, tr2 = gt(name, variant, scale, toff=toff, delay=delay)
                rec(f"{tag} ours vs GT shifted {toff*1000:+.2f} ms", res.images, tr2)
        print("elapsed", time.time() - t0, flush=True)
json.dump(rows, open(f"e2_{name}_{scale}{'_vmaf' if vm else ''}.json", "w"), indent=1)
