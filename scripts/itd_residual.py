"""Can the binaural recordings' ITD be learned beyond the spherical head? The residual of each
validation clip's true ITD from the fitted Woodworth head, predicted by its k nearest training
clips (in listener position and direction to the source, directions weighted by wdir), with the
median ITD error (us) and lateralisation agreement (%) of head + predicted residual, and the
head's error by listener distance.

    .venv/bin/python scripts/itd_residual.py data/presets/office_0 data/presets/house_0
"""
import sys, math, numpy as np, torch
sys.path.insert(0, "scripts")
from itd_table import theta_of, summary
from avgs.acoustics.interaural import woodworth_shape, fit_scale
from avgs.data.rwavs import RWAVSScene
from avgs.evaluation import spatial
for sd in sys.argv[1:]:  # noqa: one scene per argument
    s = RWAVSScene(sd); fs = s.sample_rate
    tr = [spatial.itd(c.binaural, fs) for c in s.train]; va = [spatial.itd(c.binaural, fs) for c in s.val]
    tht = np.array([theta_of(c, s.source) for c in s.train]); thv = np.array([theta_of(c, s.source) for c in s.val])
    sc = fit_scale(tht, tr)
    wt = -sc*woodworth_shape(torch.tensor(tht)).numpy(); wv = -sc*woodworth_shape(torch.tensor(thv)).numpy()
    res = np.array(tr) - wt
    Xt = np.array([[*c.listener[:2], math.cos(t), math.sin(t)] for c, t in zip(s.train, tht)])
    Xv = np.array([[*c.listener[:2], math.cos(t), math.sin(t)] for c, t in zip(s.val, thv)])
    print(sd, "woodworth", summary(va, wv))
    for k in (1, 3, 5, 10):
        for wdir in (0.5, 1, 2):
            W = np.array([1, 1, wdir, wdir])
            d = np.linalg.norm((Xv[:, None] - Xt[None]) * W, axis=-1)
            idx = np.argsort(d, 1)[:, :k]
            pred = wv + np.median(res[idx], 1)
            print(" k", k, "wdir", wdir, summary(va, list(pred)))
    # distance
    dist = np.array([np.linalg.norm(s.frame.to_world(c.listener) - s.source) for c in s.val])
    e = np.abs(np.array(va) - wv)*1e6
    for lo, hi in ((0, 2), (2, 4), (4, 100)):
        m = (dist >= lo) & (dist < hi); print(" dist", lo, hi, m.sum(), np.median(e[m]) if m.any() else None)
