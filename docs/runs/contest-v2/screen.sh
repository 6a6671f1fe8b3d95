#!/usr/bin/env bash
# screen.sh ANT SPIDER OUT N SEED : the three contest checks on N starts from SEED (the protocol's own evaluate calls)
set -e
# A run of the contest checks outside reproduce (the selection screen of docs/CONTEST.md)
A=$1; S=$2; O=$3; N=$4; SEED=$5
PY="triplesumo"
$PY evaluate --learner ant --policy $A --policies spider=passive bug=passive --baselines --epochs $N --seed $SEED --out $O/ant-pushes --no-progress --n-threads 1 > $O.log 2>&1
$PY evaluate --learner spider --policy $S --policies ant=passive bug=passive --baselines --epochs $N --seed $SEED --out $O/spider-pushes --no-progress --n-threads 1 >> $O.log 2>&1
$PY evaluate --learner spider --policy $S --policies ant=$A bug=passive --baselines --epochs $N --seed $SEED --out $O/match --no-progress --n-threads 1 >> $O.log 2>&1
python3 - $O <<'PY'
import json,sys
o=sys.argv[1]
r={}
for k in ("ant-pushes","spider-pushes","match"):
    c=next(iter(json.load(open(f"{o}/{k}/summary.json"))["candidates"].values()))
    r[k]=(c["n_win"],c["n_loss"],c["n_draw"],c["n"])
a=r["ant-pushes"]; s=r["spider-pushes"]; m=r["match"]
print(o, "ant pushes %.2f"%(a[0]/a[3]), "spider pushes %.2f"%(s[0]/s[3]), "team MWR %+.3f (W %d L %d D %d)"%((m[1]-m[0])/m[3], m[1], m[0], m[2]))
PY
