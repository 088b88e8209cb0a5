#!/usr/bin/env python3
"""The table of docs/reconstruction.md, "δ̂ from the data against the truth residual", from the reconstruct.json
files of scripts/measure_stopping.sh (300 iterations, rule off, δ̂ recorded): per cell the truth residual, the
estimator at the truth and at the iterate, the constant model, the best iterate, τ_best and where the rule with
τ = 0.65 / 0.75 / 0.8 would stop (the rule only stops, never alters an iterate), then the means per size and system."""
import json, sys, numpy as np
taus=[0.65,0.75,0.8]
rows=[]
for p in sys.argv[1:]:
    j=json.load(open(p)); st=j['stopping']; ne=st['noise_estimate']; yn=st['noise_norm']/ne['relative']
    res=np.array(j['residual']); psnr=np.array(st['psnr_per_iteration'])
    est=st['noise_norm_per_estimate']; ks=np.array([e[0] for e in est]); ds=np.array([e[1] for e in est])/yn
    best=int(np.argmax(psnr))+1
    rb=res[best] if best<len(res) else j['final_residual']
    def d_at(k):
        i=np.searchsorted(ks,k,side='right')-1; return ds[i] if i>=0 else 0
    stops={}
    for t in taus:
        s=None
        for k in range(2,len(res)+1):
            if d_at(k)>0 and res[k-1]<=t*d_at(k): s=k-1; break
        stops[t]=(s,psnr[s-1]) if s else (300,psnr[-1])
    size,sysn,scene=p.split('/')[-5:-2]
    rows.append((int(size[1:]),sysn,scene,st['truth_residual'],st['truth_spread_estimate'],ds[-1],ne['monte_carlo_model_norm']/yn,best,psnr[best-1],rb/d_at(best+1),stops,psnr[-1]))
print("| size, system, scene | ‖y − Φ_o x‖/‖y‖ (truth) | estimator at x_true | δ̂ at the iterate (300) | constant model | best iterate (dB) | τ_best = ‖y − Φθ_best‖/δ̂ | **τ = 0.65**: stop (dB) | τ = 0.75 | τ = 0.8 | 300 it. (dB) |")
print("|---|---|---|---|---|---|---|---|---|---|---|")
for r in sorted(rows):
    st=r[10]
    f=lambda s: ("cap" if s[0]==300 else str(s[0]))+f" ({s[1]:.2f})"
    print(f"| {r[0]}², {r[1].upper()}, {r[2]} | {r[3]:.4f} | {r[4]:.4f} | {r[5]:.4f} | {r[6]:.4f} | {r[7]} ({r[8]:.2f}) | {r[9]:.2f} | **{f(st[0.65])}** | {f(st[0.75])} | {f(st[0.8])} | {r[11]:.2f} |")
for size in (128,256,512):
  for sysn in ('sp','msp'):
    rr=[r for r in rows if r[0]==size and r[1]==sysn]
    if not rr: continue
    m=lambda f: np.mean([f(r) for r in rr])
    print(f"mean {size} {sysn} n={len(rr)}: best {m(lambda r:r[8]):.2f} τ.65 {m(lambda r:r[10][0.65][1]):.2f} τ.75 {m(lambda r:r[10][0.75][1]):.2f} τ.8 {m(lambda r:r[10][0.8][1]):.2f} 300 {m(lambda r:r[11]):.2f} ratio est/truth {m(lambda r:r[5]/r[3]):.3f} (min {min(r[5]/r[3] for r in rr):.3f} max {max(r[5]/r[3] for r in rr):.3f}) at-truth/truth {m(lambda r:r[4]/r[3]):.4f} tau_best {min(r[9] for r in rr):.2f}-{max(r[9] for r in rr):.2f}")
