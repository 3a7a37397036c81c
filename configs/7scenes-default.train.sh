#!/usr/bin/env bash
# How the bundled rgb2cloud-7scenes model and every run compared with it were trained, command by
# command, on a 2-core CPU. `rgb2cloud report --recipe` copies this file into docs/quality.md.
# configs/7scenes-default.yaml is the recipe that steps 1-8 start from: 0.3.0 trained it on frames
# 0-759, and 0.4.0 is the same recipe refit on the whole train split, 0-799 (step 8). Then
# 0.5.0 adds dilated residual blocks (-s 'generator.dilations=[1, 2, 4, 8, 4, 2]') and is refit the
# same way (step 9). 0.6.0 is 0.5.0's recipe trained on depth registered to the colour camera (step 19),
# 0.7.0 is 0.6.0's weights with a colour-weighted median at inference (step 22), and the published 0.8.0
# is the same with the median's taps farther apart (step 23). Runs with -s generator.dropout=0 predate
# the dropout.
set -eu

# The unseen TUM frame that the evaluation commands after this script score is read in place
# through a one-row manifest written here (paths relative to runs/; TUM depth is 5000 units per m).
mkdir -p runs
{ echo rgb,depth,depth_scale,fx,fy,cx,cy
  echo ../../shared/data/tum-fr3-office/TUM_color.png,../../shared/data/tum-fr3-office/TUM_depth.png,5000,535.4,539.2,320.1,247.6
} > runs/tum-fr3-office.csv

# 1. The previous default (0.2.0: 1400 steps, no dropout) and, on the same budget, the paper's
#    objective alone (the ablation). Run side by side, one thread each: about 72 min.
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s generator.dropout=0 \
    -s train.out_dir=runs/7scenes-default
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s generator.dropout=0 -s loss.l1_depth=0 \
    -s train.out_dir=runs/7scenes-default-paper-objective

# 2. A longer run, compared in the report but not published: the 1400-step run continued to 4600
#    steps with a warm restart (the learning rate back at 0.0002, then falling linearly to zero over the
#    last 1400 steps), about 95 more minutes on 2 threads.
mkdir -p runs/7scenes-long
cp -r runs/7scenes-default/checkpoints runs/7scenes-long/
rgb2cloud train configs/7scenes-default.yaml --resume -s train.out_dir=runs/7scenes-long -s generator.dropout=0 \
    -s train.steps=4600 -s optim.decay_start=3200 -s optim.decay_steps=1400 -s train.threads=2

# 3. Two single changes to step 1's recipe on its budget, side by side at one thread each (about
#    72 min): the paper's noise input Z as dropout 0.5 (published as 0.3.0, chosen on validation
#    REL), and virtual camera turns of up to 10 degrees about each axis.
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s generator.dropout=0 \
    -s data.transform.rotate_deg=10 -s train.out_dir=runs/7scenes-rot10

# 4. Two single changes to step 3's published recipe, side by side at one thread each (about 75 min):
#    0.3.0's run continued to 2800 steps with step 2's warm restart (the learning rate back at 0.0002,
#    then falling linearly to zero over the last 1200 steps), and the 1400-step recipe without mirror
#    augmentation (7-Scenes colour and depth come from two cameras side by side, and a mirrored pair
#    flips the offset between them).
mkdir -p runs/7scenes-dropout-long
cp -r runs/7scenes-dropout/checkpoints runs/7scenes-dropout-long/
rgb2cloud train configs/7scenes-default.yaml --resume -s train.out_dir=runs/7scenes-dropout-long \
    -s train.steps=2800 -s optim.decay_start=1600 -s optim.decay_steps=1200 -s train.threads=1
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s data.transform.flip=false \
    -s train.out_dir=runs/7scenes-noflip

# 5. Both lowered the validation REL (0.172 -> 0.145 and 0.163), so the run without mirroring was
#    continued the same way, on 2 threads (about 45 min); it reached 0.150. None of steps 4-5 is
#    published: the test split did not confirm the validation gain (docs/quality.md).
mkdir -p runs/7scenes-noflip-long
cp -r runs/7scenes-noflip/checkpoints runs/7scenes-noflip-long/
rgb2cloud train configs/7scenes-default.yaml --resume -s data.transform.flip=false \
    -s train.out_dir=runs/7scenes-noflip-long -s train.steps=2800 -s optim.decay_start=1600 \
    -s optim.decay_steps=1200 -s train.threads=2

# 6. Steps 4-5 showed that frames 780-799 cannot rank runs: their views are next to the training
#    views, while the test views are new. `rgb2cloud novelty ../shared/data/7scenes-redkitchen
#    0-759:780-799 0-759:850-999 0-669:720-799` measures it from the camera poses (closest
#    training view, median over the held-out frames): 0.04 m / 14.2 deg for 780-799, 0.19 m /
#    20.6 deg for the test split. So these runs repeat the split's own shape one level down:
#    train on 0-669, leave a 50-frame gap, select on 720-799 (0.59 m / 19.3 deg, as new as the test
#    views). Each keeps a moving average of G's weights (optim.ema; TensorBoard val_raw/* scores the
#    raw weights beside it), and the second adds the 200 aims-lab frames (another room, another
#    camera). Side by side, one thread each (about 85 min). Decided before scoring them: a change is
#    kept only if it lowers REL on 720-799 at the selected step by at least 0.01; the test split then
#    scores both runs once, whatever it says.
SELECT_TRAIN='{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "0-669"}'
SELECT_VAL='data.val=[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "720-799"}]'
# aims-lab is read in place through a manifest written here (its intrinsics are not published,
# so it borrows 7-Scenes' 585/585/320/240; depth is in millimetres).
{ echo rgb,depth,depth_scale,fx,fy,cx,cy
  for i in $(seq 0 199); do
      echo "../../shared/data/aims-lab/rgb/$i.jpg,../../shared/data/aims-lab/depth/$i.png,1000,585,585,320,240"
  done; } > runs/aims-lab.csv
AIMS='{format: csv, root: runs/aims-lab.csv, licence: "aims-lab (CMU-AI-Maker-Space/aims-slam): MIT licence"}'
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s optim.ema=0.997 -s "data.train=[$SELECT_TRAIN]" \
    -s "$SELECT_VAL" -s train.out_dir=runs/select-base
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s optim.ema=0.997 \
    -s "data.train=[$SELECT_TRAIN, $AIMS]" -s "$SELECT_VAL" -s train.out_dir=runs/select-aims
# Outcome (TensorBoard val/rel = the average, val_raw/rel = the raw weights, on 720-799): neither
# change is kept. The average's best REL was 0.244 against the raw weights' 0.214 (both at
# their best step); aims-lab raised it to 0.256 (average) and 0.239 (raw). The raw REL was
# lowest at step 600 and rose to 0.252 by step 1400: on new views, longer training on one path
# overfits, which is also what the test split said of steps 4-5. 0.3.0 stays published.

# 7. Step 6's raw weights did best on 720-799 at step 600, at the full learning rate, and got worse
#    after it. So two shorter schedules of the 0.3.0 recipe (no average), side by side at one thread
#    each (about 55 min): 700 steps with the rate falling to zero over steps 300-700, and 1000 steps
#    with it falling over steps 400-1000. Validation every 100 steps.
#    Decided before running them: a schedule replaces the 1400-step one if its *last* checkpoint
#    (what a refit publishes) has a REL on 720-799 at least 0.01 below the 1400-step recipe's
#    last checkpoint, 0.252 (step 6, runs/select-base, val_raw/rel at step 1400); if both do, the
#    lower one wins. The winner is refit on frames 0-799 with no validation frames and its last.pt
#    is published as 0.4.0; the test split scores it once afterwards and is reported whatever it says.
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "data.train=[$SELECT_TRAIN]" -s "$SELECT_VAL" \
    -s train.steps=700 -s optim.decay_start=300 -s optim.decay_steps=400 -s train.val_every=100 \
    -s train.out_dir=runs/select-700
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "data.train=[$SELECT_TRAIN]" -s "$SELECT_VAL" \
    -s train.steps=1000 -s optim.decay_start=400 -s optim.decay_steps=600 -s train.val_every=100 \
    -s train.out_dir=runs/select-1000
# Outcome (TensorBoard val/rel on 720-799): neither schedule is kept. The last checkpoints scored
# REL 0.252 (700 steps) and 0.255 (1000 steps) against the 1400-step recipe's 0.252. Both runs'
# REL moved by up to 0.05 between checkpoints 100 steps apart (700 steps: 0.222 at 400, 0.268 at
# 500), so a schedule cannot be ranked by any single checkpoint on this budget.

# 8. The refit, decided before it runs: 0.3.0's recipe, unchanged (1400 steps, chosen in steps 3-7),
#    trained on the whole train split, frames 0-799, with no validation frames; its last.pt is
#    published as 0.4.0. 0.3.0 never saw frames 760-799, the stretch of the camera path that ends
#    nearest the test frames. The test split scores it once afterwards and is reported whatever it
#    says. One run on 2 threads (about 45 min).
rgb2cloud train configs/7scenes-default.yaml -s train.threads=2 \
    -s 'data.train=[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "0-799"}]' \
    -s 'data.val=[]' -s train.out_dir=runs/refit-0-799
# Outcome: published as 0.4.0. On the test split, scored once afterwards by rgb2cloud report, it
# improves on 0.3.0 in six of the seven columns and ties delta3 at 0.996 (REL 0.122 -> 0.115,
# delta1 0.871 -> 0.891), but it still misses the paper's REL, log10 and delta1.

# 9. Where the error is: on 720-799, runs/select-1000's last checkpoint over-predicts depth on
#    every frame (ground-truth / predicted median 0.81 +- 0.04, at most 0.92), and rescaling each
#    prediction by that one number cuts REL from 0.255 to 0.105; on its own training frames 0-669
#    the ratio is 1.01 +- 0.03 (`rgb2cloud evaluate runs/select-1000/checkpoints/last.pt --format
#    7scenes --root ../shared/data/7scenes-redkitchen --frames 720-799 --median-scaled`, and
#    --frames 0-669; the per-image ratios land in metrics.json). The error on new views is mostly one
#    wrong distance per view, a room-scale cue that a 3x3 stack at 1/16 of the frame sees only in
#    part. So the residual blocks' first convolutions are dilated 1, 2, 4, 8, 4, 2 (same weights,
#    same compute): the selection run on step 6's split, and in parallel, to fit one session, the
#    refit it would publish; one thread each (about 80 min).
#    Decided before running them: the dilations are kept if the selection run's REL on 720-799,
#    averaged over its last three checkpoints (steps 1000, 1200, 1400; single checkpoints swing by
#    0.05, step 7), is at least 0.01 below the 1400-step recipe's, 0.250 (runs/select-base,
#    val_raw/rel 0.241, 0.258, 0.252). If kept, the refit's last.pt is published as 0.5.0; either
#    way the test split scores the refit once afterwards and the report shows it.
DILATED='generator.dilations=[1, 2, 4, 8, 4, 2]'
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=[$SELECT_TRAIN]" \
    -s "$SELECT_VAL" -s train.out_dir=runs/select-dilated
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" \
    -s 'data.train=[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "0-799"}]' \
    -s 'data.val=[]' -s train.out_dir=runs/refit-dilated
# Outcome (TensorBoard val/rel on 720-799): the dilations are kept. REL at steps 1000, 1200, 1400:
# 0.235, 0.228, 0.217, mean 0.227 against 0.250; the last checkpoint alone 0.217 against 0.252.
# The over-prediction shrank but stayed: median ratio 0.837 +- 0.039 at step 1400 (0.81 before),
# median-scaled REL 0.099 (0.105 before). runs/refit-dilated's last.pt is published as 0.5.0.

# 10. Where 0.5.0's test error is: per test image the ground-truth / predicted median is
#     1.001 +- 0.068, and rescaling each prediction by it would move REL only from 0.102 to 0.097
#     (docs/quality.md), so most of the error is the shape within each view, not one wrong distance.
#     The masked L1 weighs an edge pixel no more than any other. So step 9's recipe adds MegaDepth's
#     multi-scale gradient matching on the encoded (log) depth (loss.gradient_matching=50, half the
#     L1's weight; a per-view scale error costs it nothing): the selection run on step 6's split and,
#     in parallel, the refit it would publish; one thread each (about 80 min).
#     Decided before running them, as in step 9: the term is kept if the selection run's REL on
#     720-799, averaged over its last three checkpoints (steps 1000, 1200, 1400), is at least 0.01
#     below step 9's dilated run, 0.227 (runs/select-dilated: 0.235, 0.228, 0.217). If kept, the
#     refit's last.pt is published as 0.6.0; either way the test split scores the refit once
#     afterwards and the report shows it.
GRAD='loss.gradient_matching=50'
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "$GRAD" \
    -s "data.train=[$SELECT_TRAIN]" -s "$SELECT_VAL" -s train.out_dir=runs/select-gradient
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "$GRAD" \
    -s 'data.train=[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "0-799"}]' \
    -s 'data.val=[]' -s train.out_dir=runs/refit-gradient
# Outcome (TensorBoard val/rel on 720-799): the term is not kept, and 0.5.0 stays published. REL at
# steps 1000, 1200, 1400: 0.242, 0.256, 0.229, mean 0.242 against 0.227: worse, not 0.01 better.
# The shape within each view barely moved (median-scaled REL 0.097 against 0.099) and the
# over-prediction of distance did not shrink (median ratio 0.826 +- 0.041 against 0.837;
# `rgb2cloud evaluate runs/select-gradient/checkpoints/last.pt --format 7scenes --root
# ../shared/data/7scenes-redkitchen --frames 720-799 --median-scaled`). The refit was scored on the
# test split once afterwards, as a compared row of docs/quality.md, and there it does better than
# 0.5.0 in six of seven columns (delta1 0.924 against 0.915, delta2 0.987 against 0.979, REL equal at
# 0.102). It is still not published: the rule above was fixed on validation frames before the runs,
# and publishing it now would choose the model by the test split. Nor is that gain evidence for the
# term: on the same test split the two selection runs (0-669, with and without it) tie, REL 0.105
# against 0.106 and delta1 0.909 against 0.908, so the refits' gap is within what one GAN run
# varies by. For the third time (steps 4-5
# the other way round) 720-799 and the test split rank two runs differently, so the next change
# needs a selection protocol that is fixed before it runs and that does not lean on one slice.

# 11. A selection protocol that does not lean on one slice, fixed here before any of its runs, and the
#     change it tests. The change: 0.5.0's test error is mostly the shape within each view (step 10),
#     and the generator rebuilds every edge and thin object from its 1/8-scale bottleneck through three
#     transposed convolutions. generator.skips=true adds each encoder stage's output to the decoder
#     output of the same size (U-Net style, no new weights, same file size and nearly the same compute).
#     The protocol: two folds, each a block of 80 train-split frames held out with a 50-frame gap on
#     both sides. Fold A is step 6's (train 0-669, validate on 720-799); fold B validates on 220-299 and
#     trains on 0-169 and 350-799. Fold B was picked from every 80-frame block (start a multiple of 20)
#     as the one whose views are most like the test split's: `rgb2cloud novelty
#     ../shared/data/7scenes-redkitchen 0-799:850-999 0-669:720-799 0-169,350-799:220-299` gives
#     0.18 m / 14.2 deg (test), 0.59 m / 19.3 deg (A), 0.30 m / 12.5 deg (B).
#     A run's score on a fold is its REL there averaged over steps 1000, 1200 and 1400. Three runs,
#     side by side at one thread each (about 110 min): 0.5.0's recipe on fold B (its fold A run is
#     step 9's, 0.227) and the change on both folds.
#     Decided before running them: the skips are kept only if (1) their mean score over the two folds
#     is at least 0.01 below the recipe's and (2) they are not worse on either fold. If kept, the
#     recipe plus skips is refit on 0-799 and its last.pt published as 0.6.0. Either way, the test split
#     scores the two skip runs once afterwards and the report shows them.
FOLD_B_TRAIN='[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "0-169,350-799"}]'
FOLD_B_VAL='data.val=[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "220-299"}]'
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=$FOLD_B_TRAIN" \
    -s "$FOLD_B_VAL" -s train.out_dir=runs/foldb-dilated
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s generator.skips=true \
    -s "data.train=[$SELECT_TRAIN]" -s "$SELECT_VAL" -s train.out_dir=runs/folda-skips
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s generator.skips=true \
    -s "data.train=$FOLD_B_TRAIN" -s "$FOLD_B_VAL" -s train.out_dir=runs/foldb-skips
# Outcome (TensorBoard val/rel at steps 1000, 1200, 1400; the three runs took 104 min side by side):
# the skips are not kept, and 0.5.0 stays published. They were worse on both folds. On fold A they
# scored 0.254, 0.234, 0.226 (mean 0.238) against 0.227. On fold B they scored 0.104, 0.085, 0.090
# (mean 0.093) against the recipe's 0.076, 0.079, 0.075 (mean 0.077). Mean over the folds: 0.166
# against 0.152. The new fold has its own baseline: 0.5.0's recipe is far better on it (REL 0.077,
# delta1 0.965 at step 1400) than on fold A (0.227), so the two folds rank views of different
# difficulty but agree on this change.
# The test split scored the three runs once afterwards (docs/quality.md). On fold A's training frames,
# the skips lost there too: REL 0.116 and delta1 0.877, against 0.106 and 0.908 for step 9's run. On
# fold B's they won REL, RMSE, log10 and point-cloud RMSE: REL 0.101 against 0.110. They tied delta1
# (0.910 against 0.911) and lost delta2 (0.984 against 0.987). So the test split half agrees with the
# two folds, and the same recipe on two training sets moves test REL by 0.004 (step 9's fold A run
# 0.106, fold B 0.110). Gains smaller than that need more than one run per arm to see.

# 12. How much of that is the seed: 0.5.0's recipe on fold A again with train.seed=1, alone on
#     2 threads (about 40 min). A measurement for the protocol, not a candidate: it is not test-scored.
rgb2cloud train configs/7scenes-default.yaml -s train.threads=2 -s "$DILATED" -s "data.train=[$SELECT_TRAIN]" \
    -s "$SELECT_VAL" -s train.seed=1 -s train.out_dir=runs/folda-dilated-seed1
# Outcome (val/rel on 720-799 at steps 1000, 1200, 1400): 0.170, 0.223, 0.220, mean 0.204, against
# seed 0's 0.227 (step 9). The seed alone moves a fold's score by 0.023, more than the 0.01 margin of
# steps 9-11's rules and more than the skips lost by on fold A (0.011). So step 11's "not kept" holds by
# its rule, but it is weak evidence either way. A rule that can separate changes of this size needs at
# least two seeds per arm on each fold.

# 13. Step 12 measured how much one run differs from the next (a seed moves a fold's score by 0.023), so
#     this step tests the plain remedy for run-to-run spread: serve the mean of two runs' generators (their
#     tanh outputs averaged, i.e. the geometric mean of their depths) instead of one run. It doubles the
#     generator's compute, which step 9's 58 ms per 640x480 image has room for under the 300 ms limit.
#     Three runs, side by side at one thread each (about 110 min): a second seed of 0.5.0's recipe on
#     each fold (fold A already has seeds 0 and 1, but seed 0's checkpoints were not kept, so fold A pairs
#     seeds 1 and 2; fold B pairs step 11's seed 0 with seed 1), and the refit that would be published
#     beside 0.5.0 (0.5.0 is seed 0 of the same refit).
#     Decided before running them: on each fold, `rgb2cloud evaluate` scores the two members' last
#     checkpoints alone and as one ensemble on the fold's validation frames. The ensemble is kept only if
#     (1) its REL, averaged over the two folds, is at least 0.01 below its members' mean REL, averaged
#     the same way (a single run is what the members' mean estimates), and (2) it is below its members'
#     mean on each fold. If kept, 0.5.0's generator and the seed-1 refit are published together as 0.6.0,
#     with their weights stored as float16 to stay under the 20 MB limit, and only if it also meets the
#     300 ms limit (python bench/serving.py). Either way, the test split scores the seed-1 refit once
#     afterwards.
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=[$SELECT_TRAIN]" \
    -s "$SELECT_VAL" -s train.seed=2 -s train.out_dir=runs/folda-dilated-seed2
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=$FOLD_B_TRAIN" \
    -s "$FOLD_B_VAL" -s train.seed=1 -s train.out_dir=runs/foldb-dilated-seed1
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s train.seed=1 \
    -s 'data.train=[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "0-799"}]' \
    -s 'data.val=[]' -s train.out_dir=runs/refit-dilated-seed1
# Outcome (`rgb2cloud evaluate` of the last checkpoints on each fold's validation frames, full 640x480;
# the three runs took about 108 min side by side): the ensemble is not kept, and 0.5.0 stays published.
# Fold A (720-799): seed 1 REL 0.2197, seed 2 0.2240, their mean 0.2219; the ensemble 0.2200, 0.0019 better.
# Fold B (220-299): seed 0 REL 0.0749, seed 1 0.0815, their mean 0.0782; the ensemble 0.0754, 0.0028 better.
# Averaged over the folds it gains 0.0023 REL, a quarter of the 0.01 the rule asks for, at twice the
# compute, and on both folds it is a little worse than its better member. Averaging two runs can only
# cancel the error they do not share, so most of one run's error on new views is shared by both seeds'
# runs: it comes with the recipe and the data, not with the seed. (Step 12's spread, 0.170 against 0.235
# at step 1000, was between checkpoints mid-schedule; at step 1400 fold A's three seeds score 0.217,
# 0.220 and 0.224.)
# The commands that scored them:
#   R=../shared/data/7scenes-redkitchen
#   rgb2cloud evaluate runs/folda-dilated-seed1/checkpoints/last.pt runs/folda-dilated-seed2/checkpoints/last.pt \
#       --format 7scenes --root $R --frames 720-799 --out runs/folda-ensemble/eval-val
#   rgb2cloud evaluate runs/foldb-dilated/checkpoints/last.pt runs/foldb-dilated-seed1/checkpoints/last.pt \
#       --format 7scenes --root $R --frames 220-299 --out runs/foldb-ensemble/eval-val
#   and each checkpoint alone the same way. The test split scored the seed-1 refit once afterwards
#   (docs/quality.md, "0.5.0's recipe with seed 1").

# 14. On fold A most of the error on new views is one wrong distance per view: step 9's run sees every
#     view too far (ground-truth / predicted median 0.837 +- 0.039), and rescaling each prediction by that
#     one number cuts its REL from 0.217 to 0.099 (`rgb2cloud evaluate ... --median-scaled`, step 9).
#     The generator normalises every layer per image and per channel (instance norm, as pix2pixHD),
#     which removes each image's feature means, so a view's absolute distance can only be coded in the
#     spatial shape of its features.
#     generator.global_offset=true adds one path that sets it directly: a 1x1 convolution and ReLU over
#     the bottleneck after the residual blocks, their mean over the map, and a 1x1 convolution to one
#     log-depth offset per image, added before the output's tanh (8,300 weights; it starts at zero, so
#     training starts from the plain network). Three runs, side by side at one thread each (about
#     110 min): the change on each fold, and the refit that would publish it, all seed 0.
#     Decided before running them, with step 13's runs as the baseline (REL of the last checkpoints on
#     the fold's validation frames, full 640x480, `rgb2cloud evaluate` as in step 13): the recipe's
#     two-seed mean is 0.2219 on fold A and 0.0782 on fold B, 0.1500 averaged. The offset is kept only
#     if (1) its REL averaged over the two folds is at most 0.1400 (0.01 below; one run per fold, and at
#     step 1400 seeds of the recipe differ by 0.004 on fold A and 0.007 on fold B), and (2) it is below
#     the recipe's two-seed mean on each fold. If kept, the refit's last.pt is published as 0.6.0,
#     provided it meets the 300 ms and 20 MB limits. Either way the test split scores the refit once
#     afterwards and the report shows it.
OFFSET='generator.global_offset=true'
# From step 14 on, each step runs one change (the -s overrides after its name) on 0.5.0's recipe three times: on
# fold A, on fold B, and refit on 0-799 with no validation frames, as runs/folda-NAME, runs/foldb-NAME
# and runs/refit-NAME. They ran side by side at one thread each.
try_change() {
    name=$1
    shift
    rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" "$@" \
        -s "data.train=[$SELECT_TRAIN]" -s "$SELECT_VAL" -s train.out_dir="runs/folda-$name"
    rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" "$@" \
        -s "data.train=$FOLD_B_TRAIN" -s "$FOLD_B_VAL" -s train.out_dir="runs/foldb-$name"
    rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" "$@" \
        -s 'data.train=[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "0-799"}]' \
        -s 'data.val=[]' -s train.out_dir="runs/refit-$name"
}
try_change offset -s "$OFFSET"
# Outcome (`rgb2cloud evaluate` of the last checkpoints on each fold's validation frames, full 640x480,
# with --median-scaled; the three runs took about 102 min side by side): the offset is not kept, and 0.5.0
# stays published. Fold A (720-799): REL 0.2197 against the recipe's two-seed mean 0.2219 (0.0022 better);
# fold B (220-299): 0.0855 against 0.0782 (0.0073 worse). Averaged over the folds 0.1526 against 0.1500:
# worse, where the rule asked for 0.1400. Nor did it touch what it was for: on fold A every view is still
# seen too far, ground-truth / predicted median 0.825 +- 0.045 (step 9's run: 0.837 +- 0.039), and
# median-scaled REL 0.089. So a view's distance is not lost to instance norm: with a direct path for it,
# the network still reads new views as farther than they are. The scale error on new views comes from
# what the training views teach, not from where the network could put the number.
# The commands that scored them:
#   rgb2cloud evaluate runs/folda-offset/checkpoints/last.pt --format 7scenes --root $R --frames 720-799 \
#       --median-scaled --out runs/folda-offset/eval-val
#   rgb2cloud evaluate runs/foldb-offset/checkpoints/last.pt --format 7scenes --root $R --frames 220-299 \
#       --median-scaled --out runs/foldb-offset/eval-val
#   The test split scored the refit once afterwards (docs/quality.md, "global offset, refit on 0-799").

# 15. Steps 9 and 14 agree that, on new views, the network misjudges how far the whole view is, and
#     step 14 showed that the cause is what the training views teach, not where the network can put the
#     number. One thing they teach is wrong: every frame is enlarged by up to 10% (data.transform.scale
#     0.5-0.55 against the 0.5 that fills the crop) and keeps its depth, so the same object at the same
#     distance appears at sizes up to 10% apart. Eigen et al. (2014) enlarge by s in [1, 1.5] and divide
#     the depth by s: a zoom becomes a step closer (exact for a plane facing the camera), so the size an
#     object appears at keeps meaning one distance, and one camera path shows a wider range of distances.
#     data.transform.zoom_depth=true does that; with scale 0.5-0.75 the enlargement is 1-1.5, as theirs.
#     Three runs, side by side at one thread each (about 105 min): the change on each fold, and the refit
#     that would publish it, all seed 0.
#     Decided before running them, with step 14's rule and baseline (REL of the last checkpoints on the
#     fold's validation frames, full 640x480, `rgb2cloud evaluate` as in step 13; the recipe's two-seed
#     mean is 0.2219 on fold A and 0.0782 on fold B, 0.1500 averaged): the change is kept only if (1) its
#     REL averaged over the two folds is at most 0.1400, and (2) it is below the recipe's two-seed mean
#     on each fold. If kept, the refit's last.pt is published as 0.6.0, provided it meets the 300 ms and
#     20 MB limits. Either way the test split scores the refit once afterwards and the report shows it.
ZOOM='data.transform.scale=[0.5, 0.75]'
CLOSER='data.transform.zoom_depth=true'
try_change zoom -s "$ZOOM" -s "$CLOSER"
# Outcome (`rgb2cloud evaluate` of the last checkpoints on each fold's validation frames, full 640x480,
# with --median-scaled; the three runs took about 102 min side by side): the change is not kept, and
# 0.5.0 stays published. Fold A (720-799): REL 0.1059 against the recipe's two-seed mean 0.2219, less
# than half; fold B (220-299): 0.0906 against 0.0782, 0.0124 worse. Averaged over the folds 0.0983
# against 0.1500, well inside the 0.1400 that (1) asks for, but (2) fails on fold B. It overcorrected:
# the ground-truth / predicted median went from 0.837 +- 0.039 (step 9's run, views seen too far) to
# 1.071 +- 0.040 on fold A, and is 1.116 +- 0.066 on fold B, so both folds' views are now seen too close.
# The enlargements 1-1.5 average 1.25, every one of them brings the scene closer, and a network that
# also recognises where in the kitchen it is learns part of that shift as a property of the place.
# Median-scaled REL barely moved (fold A 0.093 against step 9's 0.099; fold B 0.102), so the change
# moved each view's distance, not its shape.
# The test split scored the refit once afterwards, as pre-registered (docs/quality.md, "zoom as a step
# closer, refit on 0-799"): REL 0.119, delta1 0.842, worse than 0.5.0 in every column; its test views
# are seen too close as well (median ratio 1.046 +- 0.047, median-scaled REL 0.103). So fold B, the
# fold whose views are most like the test split's, ranked it as the test split does, and the rule's
# second clause is what kept it out. What it leaves for a next step: distance on new views does follow
# the zoom's depth label, so an enlargement range centred on no change (a zoom out as well as in)
# should remove the new bias without the old one.
# The commands that scored them:
#   rgb2cloud evaluate runs/folda-zoom/checkpoints/last.pt --format 7scenes --root $R --frames 720-799 \
#       --median-scaled --out runs/folda-zoom/eval-val
#   rgb2cloud evaluate runs/foldb-zoom/checkpoints/last.pt --format 7scenes --root $R --frames 220-299 \
#       --median-scaled --out runs/foldb-zoom/eval-val
#   rgb2cloud evaluate runs/refit-zoom/checkpoints/last.pt --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --out runs/refit-zoom/eval-test   (the test split's scale diagnostic, after the report)

# 16. Step 15's zoom as a step closer moved the distance on new views the way it should, but too far:
#     fold A's ground-truth / predicted median went from 0.837 to 1.071 and fold B's to 1.116, with
#     enlargements 1-1.5 (mean 1.25). The ratio moved by about the mean enlargement, so an enlargement
#     range of 1-1.2 (data.transform.scale 0.5-0.6, mean 1.1) should leave fold A's views seen about 8%
#     too far instead of 16%, and fold B's within a few percent of right. The same switch, a milder range.
#     Three runs, side by side at one thread each (about 105 min): the change on each fold, and the refit
#     that would publish it, all seed 0.
#     Decided before running them, with step 14's rule and baseline (REL of the last checkpoints on the
#     fold's validation frames, full 640x480, `rgb2cloud evaluate` as in step 13; the recipe's two-seed
#     mean is 0.2219 on fold A and 0.0782 on fold B, 0.1500 averaged): the change is kept only if (1) its
#     REL averaged over the two folds is at most 0.1400, and (2) it is below the recipe's two-seed mean
#     on each fold. If kept, the refit's last.pt is published as 0.6.0, provided it meets the 300 ms and
#     20 MB limits. Either way the test split scores the refit once afterwards and the report shows it.
ZOOM12='data.transform.scale=[0.5, 0.6]'
try_change zoom12 -s "$ZOOM12" -s "$CLOSER"
# Outcome (`rgb2cloud evaluate` of the last checkpoints on each fold's validation frames, full 640x480,
# with --median-scaled; the three runs took about 101 min side by side): the rule keeps the change, but
# its refit is not published (below). Fold A (720-799): REL 0.1066 against the recipe's two-seed
# mean 0.2219; fold B (220-299): 0.0765 against 0.0782. Averaged over the folds 0.0916 against 0.1500
# (the rule asked for at most 0.1400), and below the baseline on each fold. The milder range took the
# distance most of the way to right on both folds: the ground-truth / predicted median is 0.977 +- 0.037
# on fold A (step 9's run 0.837, step 15's 1.071) and 1.038 +- 0.048 on fold B (step 15's 1.116).
# Median-scaled REL: fold A 0.096, fold B 0.090.
# Before publishing, the refit was scored on the test split and the unseen TUM frame (a card carries
# both) and it is worse than 0.5.0 on both, in every column: test REL 0.122 against 0.102, delta1 0.872
# against 0.915, log10 0.059 against 0.047; TUM delta1 0.19 against 0.33. Its test views are seen too
# close (ground-truth / predicted median 1.067 +- 0.037, where 0.5.0's is 1.001 +- 0.068), while the
# shape within each view improved (median-scaled REL 0.087 against 0.097). So the zoom shifts every
# view's distance closer by several percent: that cures fold A, whose views the recipe saw about 19%
# too far, and costs the test split, whose views it already saw at the right distance; fold B's 0.0017
# gain was too small to tell the two apart. The rule said to publish it; it is not published, and 0.5.0 stays.
# The issue asks for the model that serves users better, and on every held-out measure outside the
# train split this one serves them worse. Keeping the published model on the test split's word adds no
# optimism to any reported figure (0.5.0's were measured once, before this step); letting a new model
# through on it would, which is why steps 10 and 13 did not. From step 17 a kept change is published
# only if its refit also does not lose to the published model on the test split's REL and delta1.
# The commands that scored them:
#   rgb2cloud evaluate runs/folda-zoom12/checkpoints/last.pt --format 7scenes --root $R --frames 720-799 \
#       --median-scaled --out runs/folda-zoom12/eval-val
#   rgb2cloud evaluate runs/foldb-zoom12/checkpoints/last.pt --format 7scenes --root $R --frames 220-299 \
#       --median-scaled --out runs/foldb-zoom12/eval-val
#   rgb2cloud evaluate runs/refit-zoom12/checkpoints/last.pt --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --out runs/refit-zoom12/eval-test
#   rgb2cloud evaluate runs/refit-zoom12/checkpoints/last.pt --format csv --root runs/tum-fr3-office.csv \
#       --out runs/refit-zoom12/eval-unseen

# 17. Steps 15 and 16 agree that zoom as a step closer moves how far new views are judged, and that
#     it also sharpens their shape (test median-scaled REL 0.087 at 1-1.2 against 0.5.0's 0.097), but
#     enlargements only ever bring the scene closer, so a place's average distance shifts with them.
#     data.transform.zoom_out=true lets a scale below the crop-filling 0.5 shrink the frame inside
#     black, depth-less borders, which zoom_depth turns into a step back. With scale 0.4167-0.6 the
#     enlargement runs 1/1.2-1.2: as many steps back as closer, and the same spread as step 16.
#     Three runs, side by side at one thread each (about 105 min), all seed 0, as in steps 14-16.
#     Decided before running them, with step 14's rule and baseline (REL of the last checkpoints on the
#     fold's validation frames, full 640x480; the recipe's two-seed mean is 0.2219 on fold A and 0.0782
#     on fold B, 0.1500 averaged): the change is kept only if (1) its REL averaged over the two folds is
#     at most 0.1400, and (2) it is below the recipe's two-seed mean on each fold. A kept change's refit
#     is published as 0.6.0 only if it meets the 300 ms and 20 MB limits and (3), the gate step 16 added,
#     does not lose to 0.5.0 on the test split's REL (0.102) and delta1 (0.915). Either way the test
#     split scores the refit once and the report shows it.
ZOOM_BOTH='data.transform.scale=[0.4167, 0.6]'
OUT='data.transform.zoom_out=true'
try_change zoomout -s "$ZOOM_BOTH" -s "$CLOSER" -s "$OUT"
# Outcome (`rgb2cloud evaluate` of the last checkpoints on each fold's validation frames, full 640x480,
# with --median-scaled; the three runs took about 110 min side by side, in two sittings (resumed from
# their step-600 checkpoints)): the rule keeps the change and the gate stops it, so it is not published and 0.5.0 stays.
# Fold A (720-799): REL 0.1239 against the recipe's two-seed mean 0.2219; fold B (220-299): 0.0752
# against 0.0782. Averaged over the folds 0.0996 against 0.1500 (at most 0.1400 asked), and below the
# baseline on each fold: (1) and (2) hold. Ground-truth / predicted median: fold A 0.946 +- 0.032, fold B
# 1.031 +- 0.051; median-scaled REL 0.095 and 0.092. (3) fails: the refit's test REL is 0.115 (0.5.0:
# 0.102) and delta1 0.879 (0.915); RMSE 0.348, log10 0.055, delta2 0.974, delta3 0.990, PC RMSE 0.374;
# TUM delta1 0.23 (0.5.0: 0.33). Its test views are still seen too close (median ratio 1.054 +- 0.038),
# though less than step 16's (1.067), and the shape within each view is again better than 0.5.0's
# (median-scaled REL 0.093 against 0.097). So taking steps back as often as steps closer did not centre
# the test split's distance: with zoom_depth the network learns to read distance from how large things
# look, and the test split's views are judged closer whichever way the zoom is balanced. Three zoom
# ranges (steps 15-17) all traded the test split's distance for shape, and the trade lost each time;
# the zoom is closed as a direction on this budget.
# The commands that scored them:
#   rgb2cloud evaluate runs/folda-zoomout/checkpoints/last.pt --format 7scenes --root $R --frames 720-799 \
#       --median-scaled --out runs/folda-zoomout/eval-val
#   rgb2cloud evaluate runs/foldb-zoomout/checkpoints/last.pt --format 7scenes --root $R --frames 220-299 \
#       --median-scaled --out runs/foldb-zoomout/eval-val
#   rgb2cloud evaluate runs/refit-zoomout/checkpoints/last.pt --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --out runs/refit-zoomout/eval-test
#   rgb2cloud evaluate runs/refit-zoomout/checkpoints/last.pt --format csv --root runs/tum-fr3-office.csv \
#       --out runs/refit-zoomout/eval-unseen

# 18. Steps 15-17 moved the distance of new views and left the shape within each view as the larger
#     error on the test split (0.5.0's median-scaled REL 0.097 against 0.102 unscaled). The objective's
#     masked L1 on log depth is the term that scores depth pixel by pixel, and it is what turned the
#     paper's objective (test REL 0.139, delta1 0.801) into 0.2.0's (0.128, 0.851) in step 1; at weight 100
#     it is already the largest term (about 3 against cGAN 0.55 late in training). This step asks whether
#     weighting it 3x (300) buys more of the same, at the cost of the cGAN's share. Same three runs,
#     rule and gate as step 17: kept only if (1) its REL averaged over the two folds is at most 0.1400 and
#     (2) it is below the recipe's two-seed mean on each fold (0.2219 on A, 0.0782 on B); its refit is
#     published as 0.6.0 only if also (3) it does not lose to 0.5.0 on the test split's REL (0.102) and
#     delta1 (0.915). The generator is unchanged, so the 300 ms and 20 MB limits hold as for 0.5.0.
#     Either way the test split scores the refit once and the report shows it.
L1X3='loss.l1_depth=300'
try_change l1x3 -s "$L1X3"
# Outcome (`rgb2cloud evaluate` of the last checkpoints on each fold's validation frames, full 640x480,
# with --median-scaled; the three runs took about 126 min side by side, in two sittings (resumed from
# their step-400 checkpoints)): the rule does not keep the change, so it is not published and 0.5.0 stays.
# Fold A (720-799): REL 0.2118 against the recipe's two-seed mean 0.2219; fold B (220-299): 0.0876
# against 0.0782. Averaged over the folds 0.1497 against 0.1500 (at most 0.1400 asked), and worse than
# the baseline on fold B: (1) and (2) both fail. Ground-truth / predicted median: fold A 0.841 +- 0.041
# (fold A's views are still seen about 19% too far), fold B 0.996 +- 0.053; median-scaled REL 0.097 and
# 0.091. The refit, scored once as every refit is: test REL 0.103, RMSE 0.320, log10 0.048, delta1 0.917,
# delta2 0.979, delta3 0.992, PC RMSE 0.343 (0.5.0: 0.102, 0.319, 0.047, 0.915, 0.979, 0.992, 0.343);
# median ratio 1.010 +- 0.069, median-scaled REL 0.095 (0.5.0: 0.097); TUM delta1 0.33 (0.5.0: 0.33).
# So tripling the L1's weight moved nothing that matters: the fold means are the recipe's, and the
# test split's row is 0.5.0's to within a seed's spread (step 12). The pixel-wise L1 already sets what
# the generator learns at weight 100; the cGAN's share is not what holds the shape back.
# The commands that scored them:
#   rgb2cloud evaluate runs/folda-l1x3/checkpoints/last.pt --format 7scenes --root $R --frames 720-799 \
#       --median-scaled --out runs/folda-l1x3/eval-val
#   rgb2cloud evaluate runs/foldb-l1x3/checkpoints/last.pt --format 7scenes --root $R --frames 220-299 \
#       --median-scaled --out runs/foldb-l1x3/eval-val
#   rgb2cloud evaluate runs/refit-l1x3/checkpoints/last.pt --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --out runs/refit-l1x3/eval-test
#   rgb2cloud evaluate runs/refit-l1x3/checkpoints/last.pt --format csv --root runs/tum-fr3-office.csv \
#       --out runs/refit-l1x3/eval-unseen
# Where delta1 fails, for choosing step 19 (`rgb2cloud evaluate ... --where-fails`, validation frames only;
# a pixel is near a step when, within 3 px, the ground truth's valid depths differ by over 1.25x):
#   fold A, the recipe's two seeds: 1.7% of pixels are near steps; they fail at 67.5% / 66.7%, the rest
#     at 34.7% / 35.3%, so 3.2% / 3.1% of the failures are near steps: fold A's failures are the wrong
#     distance of whole surfaces, as its median ratio (about 0.84) says;
#   fold B, the recipe's two seeds: 3.4% of pixels are near steps; they fail at 40.1% / 38.6%, the rest
#     at 2.2% / 1.6%, so 39.2% / 45.7% of the failures are near steps;
#   step 18's runs: fold A 68.4% / 34.3% (3.3% near steps), fold B 40.5% / 1.7% (46.2%): unchanged.
# So on the most test-like views about 40-46% of delta1's failures sit in the 3.4% of pixels beside a
# depth step, and tripling the L1 did not sharpen them. 7-Scenes' colour and depth cameras are not
# registered (../shared/data/README.md), so part of that may be where the depth camera sees an edge
# that the colour camera sees a few pixels away; a change aimed at steps should be judged with this split.
#   rgb2cloud evaluate runs/folda-dilated-seed1/checkpoints/last.pt --format 7scenes --root $R \
#       --frames 720-799 --where-fails --out runs/folda-dilated-seed1/eval-where
#   (the same for folda-dilated-seed2 and folda-l1x3 on 720-799, and for foldb-dilated,
#   foldb-dilated-seed1 and foldb-l1x3 on 220-299)

# 19. Where the failures beside depth steps come from: 7-Scenes' depth is the raw Kinect depth camera's,
#     not registered to the colour camera (../shared/data/README.md). `rgb2cloud calibrate
#     ../shared/data/7scenes-redkitchen --frames 0-799 --every 40` fits where the colour camera sits by
#     aligning colour edges with depth steps on 20 train frames: focal length 530 px against the depth
#     camera's 585, principal point (314.5, 239), 9 mm to the side; alignment 0.196 against 0.127 if the
#     two were one camera. So an edge 300 px from the centre sits about 30 px apart in the two images, and
#     a network reading the photo can only learn that offset as a blur, the more so as mirroring flips it.
#     The change: data sources carry that colour_camera, so training sees depth moved into the colour
#     camera (model.registration.depth_to_colour), the depth a user's point cloud needs under each pixel
#     of the photo. Such a model is scored by reading its prediction, at each valid ground-truth pixel,
#     at the colour pixel that sees the same point (`rgb2cloud evaluate --colour-camera`): every valid
#     640x480 ground-truth pixel still counts, at its recorded depth, with no scaling. The recipe's
#     runs predict the depth camera's view and are scored pixel to pixel, as before; each table states
#     which way a row was scored, and both ways are shown for the published model and this step's refit.
#     Same three runs as steps 14-18 (about 105 min side by side).
#     Decided before running them, with step 14's rule and baseline (REL of the last checkpoints on the
#     fold's validation frames, full 640x480; the recipe's two-seed mean is 0.2219 on fold A and 0.0782
#     on fold B, 0.1500 averaged): kept only if (1) its REL averaged over the two folds is at most 0.1400
#     and (2) it is below the recipe's two-seed mean on each fold; its refit is published as 0.6.0 only if
#     also (3) it does not lose to 0.5.0 on the test split's REL (0.102) and delta1 (0.915). The generator
#     is unchanged, so the 300 ms and 20 MB limits hold as for 0.5.0. Either way the test split scores
#     the refit once and the report shows it.
COLOUR='colour_camera: {fx: 530, fy: 530, cx: 314.5, cy: 239, baseline_m: 0.009}'
REGISTERED_TRAIN_A="{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: \"0-669\", $COLOUR}"
REGISTERED_TRAIN_B="{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: \"0-169,350-799\", $COLOUR}"
REGISTERED_TRAIN="{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: \"0-799\", $COLOUR}"
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=[$REGISTERED_TRAIN_A]" \
    -s "$SELECT_VAL" -s train.out_dir=runs/folda-registered
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=[$REGISTERED_TRAIN_B]" \
    -s "$FOLD_B_VAL" -s train.out_dir=runs/foldb-registered
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=[$REGISTERED_TRAIN]" \
    -s 'data.val=[]' -s train.out_dir=runs/refit-registered
# Outcome (`rgb2cloud evaluate --colour-camera` of the last checkpoints on each fold's validation frames,
# full 640x480, with --median-scaled --where-fails; the three runs took about 115 min side by side): the
# rule keeps the change and the gate lets it through, so the refit's last.pt is published as 0.6.0.
# Fold A (720-799): REL 0.1996 against the recipe's two-seed mean 0.2219; fold B (220-299): 0.0729 against
# 0.0782. Averaged over the folds 0.1363 (at most 0.1400 asked), and below the baseline on each fold: (1)
# and (2) hold. Ground-truth / predicted median: fold A 0.846 +- 0.025 (its views are still seen about 18%
# too far), fold B 1.031 +- 0.048; median-scaled REL 0.073 and 0.083. Where delta1 fails: on fold B the
# pixels away from depth steps now fail at 0.7% (the recipe's seeds: 2.2% / 1.6%), those beside steps at
# 33.3% (40.1% / 38.6%); fold B's delta1 is 0.982. On fold A the rest fail at 26.6% (34.7% / 35.3%).
# The refit on the test split, read at the colour camera: REL 0.096, RMSE 0.279, log10 0.044, delta1 0.940,
# delta2 0.989, delta3 0.998, PC RMSE 0.300 (median ratio 0.999 +- 0.076); (3) holds against 0.5.0's
# 0.102 / 0.915. TUM frame (registered by TUM, so pixel to pixel): delta1 0.41 (0.5.0: 0.33), REL 0.302.
# Both ways, as pre-registered: the refit scored pixel to pixel on the test split gets REL 0.114, delta1
# 0.903 (it predicts the photo's view, so that misplaces its edges), and 0.5.0 read at the colour camera
# gets REL 0.092, RMSE 0.296, log10 0.042, delta1 0.927, delta2 0.987, delta3 0.996, PC RMSE 0.317. So
# 0.5.0, trained on raw depth, had mostly learnt the photo's view too, and the pixel-to-pixel protocol
# charged it for the camera offset; like for like (both read at the colour camera) 0.6.0 gains delta1
# (0.940 against 0.927), RMSE, delta2, delta3, PC RMSE and the TUM frame, and loses REL (0.096 against
# 0.092) and log10 (0.044 against 0.042). The gate was written against 0.5.0's published figures, and it
# is applied as written; the like-for-like row is in the report beside it. 0.6.0 beats the paper's
# Table 2 on REL, RMSE, log10, delta2 and delta3, and misses delta1 by 0.002 (0.940 against 0.942).
# The commands that scored them (C is the COLOUR camera above, as '{fx: 530, ...}'):
#   rgb2cloud evaluate runs/folda-registered/checkpoints/last.pt --format 7scenes --root $R --frames 720-799 \
#       --median-scaled --where-fails --colour-camera "$C" --out runs/folda-registered/eval-val
#   rgb2cloud evaluate runs/foldb-registered/checkpoints/last.pt --format 7scenes --root $R --frames 220-299 \
#       --median-scaled --where-fails --colour-camera "$C" --out runs/foldb-registered/eval-val
#   rgb2cloud evaluate runs/refit-registered/checkpoints/last.pt --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --colour-camera "$C" --out runs/refit-registered/eval-test
#   rgb2cloud evaluate runs/refit-registered/checkpoints/last.pt --format csv --root runs/tum-fr3-office.csv \
#       --median-scaled --out runs/refit-registered/eval-unseen
#   rgb2cloud evaluate runs/refit-registered/checkpoints/last.pt --format 7scenes --root $R --frames 850-999 \
#       --out runs/refit-registered/eval-test-raw   (pixel to pixel)
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.5.0 --format 7scenes --root $R --frames 850-999 \
#       --colour-camera "$C" --out runs/published-0.5.0/eval-test-colour
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.5.0 --format csv --root runs/tum-fr3-office.csv \
#       --out runs/published-0.5.0/eval-unseen   (0.5.0 left weights/ with 0.6.0; it is in git history)
#   The two rows scored both ways join the report as records (`rgb2cloud record`, README): "0.5.0 read at
#   the colour camera" from runs/published-0.5.0/, and "0.6.0's checkpoint scored pixel to pixel" from
#   runs/refit-registered/eval-test-raw and eval-unseen, each with its training command's config.
#   rgb2cloud export runs/refit-registered/checkpoints/last.pt --name rgb2cloud-7scenes --version 0.6.0 \
#       --metrics runs/refit-registered/eval-test/metrics.json --metrics runs/refit-registered/eval-unseen/metrics.json \
#       --parity-image ../shared/data/tum-fr3-office/TUM_color.png --registry weights

# 20. Step 10's multi-scale gradient matching (loss.gradient_matching=50) again, now on step 19's
#     registered depth. Step 10 tried it on raw depth, whose steps sit up to about 30 px from the colour
#     edges the network sees, so a term that rewards sharp steps in the right place had no right place to
#     reward; it moved nothing (median-scaled REL 0.097 against 0.099). Registration put the steps under
#     the edges, and on fold B the pixels beside depth steps are still where delta1 fails: 33.3% of them
#     fail against 0.7% of the rest (step 19). The term scores log-depth differences between neighbours,
#     so it sharpens steps without touching a view's distance. Same three runs as step 19, with the same
#     colour camera, side by side at one thread each (about 105 min), all seed 0.
#     Decided before running them, with step 14's rule and step 19's runs as the new baseline (REL of the
#     last checkpoints on the fold's validation frames, full 640x480, read at the colour camera with
#     `rgb2cloud evaluate --colour-camera`; 0.1996 on fold A and 0.0729 on fold B, 0.1363 averaged): the
#     change is kept only if (1) its REL averaged over the two folds is at most 0.1263 and (2) it is below
#     the baseline on each fold. Its refit is published as 0.7.0 only if also (3) it does not lose to 0.6.0
#     on the test split read at the colour camera, REL (0.096) and delta1 (0.940). The generator is
#     unchanged, so the 300 ms and 20 MB limits hold as for 0.6.0. Either way the test split scores the
#     refit once and the report shows it.
REGISTERED_GRADIENT=(-s "$DILATED" -s loss.gradient_matching=50)
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 "${REGISTERED_GRADIENT[@]}" \
    -s "data.train=[$REGISTERED_TRAIN_A]" -s "$SELECT_VAL" -s train.out_dir=runs/folda-registered-gradient
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 "${REGISTERED_GRADIENT[@]}" \
    -s "data.train=[$REGISTERED_TRAIN_B]" -s "$FOLD_B_VAL" -s train.out_dir=runs/foldb-registered-gradient
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 "${REGISTERED_GRADIENT[@]}" \
    -s "data.train=[$REGISTERED_TRAIN]" -s 'data.val=[]' -s train.out_dir=runs/refit-registered-gradient
# Outcome (`rgb2cloud evaluate --colour-camera` of the last checkpoints on each fold's validation frames,
# full 640x480, with --median-scaled --where-fails; the three runs took about 107 min side by side): the
# rule does not keep the change, so it is not published and 0.6.0 stays. Fold A (720-799): REL 0.2207
# against step 19's 0.1996, worse; fold B (220-299): 0.0723 against 0.0729. Averaged over the folds 0.1465
# against 0.1363 (at most 0.1263 asked): (1) and (2) both fail. It did not do what it was for: on fold B the
# pixels beside depth steps fail at 34.0% (step 19: 33.3%) and the rest at 0.6% (0.7%); delta1 0.982 both
# times. Fold A's views are seen farther than before (ground-truth / predicted median 0.820 +- 0.038,
# step 19: 0.846), though their shape is no worse (median-scaled REL 0.073 both times). The refit, scored
# once as every refit is, read at the colour camera: test REL 0.099, RMSE 0.285, log10 0.044, delta1 0.937,
# delta2 0.988, delta3 0.997, PC RMSE 0.307 (0.6.0: 0.096, 0.279, 0.044, 0.940, 0.989, 0.998, 0.300); median
# ratio 0.976 +- 0.092; TUM delta1 0.41 (0.6.0: 0.41). So with the steps under the edges the gradient term
# still does not sharpen them: the failures beside steps are not for want of a loss that asks for sharp
# steps.
# The commands that scored them (R and C as in step 19):
#   rgb2cloud evaluate runs/folda-registered-gradient/checkpoints/last.pt --format 7scenes --root $R \
#       --frames 720-799 --median-scaled --where-fails --colour-camera "$C" --out runs/folda-registered-gradient/eval-val
#   rgb2cloud evaluate runs/foldb-registered-gradient/checkpoints/last.pt --format 7scenes --root $R \
#       --frames 220-299 --median-scaled --where-fails --colour-camera "$C" --out runs/foldb-registered-gradient/eval-val
#   rgb2cloud evaluate runs/refit-registered-gradient/checkpoints/last.pt --format 7scenes --root $R \
#       --frames 850-999 --median-scaled --colour-camera "$C" --out runs/refit-registered-gradient/eval-test
#   rgb2cloud evaluate runs/refit-registered-gradient/checkpoints/last.pt --format csv --root runs/tum-fr3-office.csv \
#       --median-scaled --out runs/refit-registered-gradient/eval-unseen
#   The report scores the refit itself as a compared row ("gradient matching on registered depth, step 20").

# 21. The colour camera refitted with a roll. Step 19's camera model turned the colour camera about no
#     axis; the calibration now also fits a turn about the optical axis (ColourCamera.roll_deg; a turn
#     about the other two axes is, this close to the centre, a shift of the principal point, which the
#     fit has). `rgb2cloud calibrate ../shared/data/7scenes-redkitchen --frames 0-799 --every 40` finds
#     {fx: 528, fy: 528, cx: 315.5, cy: 238.5, baseline_m: 0.012, roll_deg: 0.55}, alignment 0.2194 on its
#     20 frames against step 19's camera's 0.1959 (`--compare`). On the other 20 (`--frames 20-799`, the
#     same command with --compare for both cameras) it aligns 0.2151 against 0.1935, and a fit there finds
#     the same focal length and roll (528 px, 0.55 degrees). At 300 px from the centre 0.55 degrees moves
#     an edge by 2.9 px: the 3 px beside each depth step where fold B's delta1 fails at 33% (step 19).
#     The change: training registers depth with the refitted camera (REFITTED below), nothing else; same
#     three runs as steps 19-20, side by side at one thread each (about 107 min), all seed 0.
#     Decided before running them:
#     - Every registered model is read from now on through the refitted camera, the instrument that
#       aligns better on frames its fit did not use (`rgb2cloud evaluate --colour-camera "$REFITTED"`).
#       The baseline is step 19's fold runs re-read through it (their REL on each fold, and the mean);
#       those numbers come from the existing checkpoints and are written here before this step's runs
#       are scored.
#     - Step 14's rule on that baseline: kept only if (1) its REL averaged over the two folds is at most
#       the baseline's mean less 0.01 and (2) it is below the baseline on each fold.
#     - Its refit is published as 0.7.0 only if also (3) it does not lose to 0.6.0 on the test split
#       read through the refitted camera, REL and delta1. 0.6.0's test row is re-read through it once, for
#       that gate and for the report, whatever it says; its step-19 reading stays beside it.
#     - A published model's own row in the report and on its card stays as it was scored when published,
#       through the camera it trained with (cards are not rewritten); a re-read through another camera is
#       a compared row beside it (`rgb2cloud record`), as step 19 showed 0.5.0 both ways.
#     The generator is unchanged, so the 300 ms and 20 MB limits hold as for 0.6.0. Either way the test
#     split scores the refit once and the report shows it.
#     The baseline, written before this step's runs were scored: step 19's last checkpoints re-read through
#     the refitted camera give REL 0.1997 on fold A and 0.0744 on fold B (read through step 19's camera:
#     0.1996 and 0.0729), 0.1370 averaged, so (1) asks for at most 0.1270. Fold B's delta1 0.980 (0.982),
#     its pixels beside depth steps failing at 33.8% (33.3%): a model trained on step 19's registration
#     placed its edges where that registration put them, not better seen through the refitted camera.
#       rgb2cloud evaluate runs/folda-registered/checkpoints/last.pt --format 7scenes --root $R \
#           --frames 720-799 --median-scaled --where-fails --colour-camera "$REFITTED" \
#           --out runs/folda-registered/eval-val-refitted
#       (the same for runs/foldb-registered on 220-299)
REFITTED='{fx: 528, fy: 528, cx: 315.5, cy: 238.5, baseline_m: 0.012, roll_deg: 0.55}'
REFIT_TRAIN_A="{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: \"0-669\", colour_camera: $REFITTED}"
REFIT_TRAIN_B="{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: \"0-169,350-799\", colour_camera: $REFITTED}"
REFIT_TRAIN="{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: \"0-799\", colour_camera: $REFITTED}"
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=[$REFIT_TRAIN_A]" \
    -s "$SELECT_VAL" -s train.out_dir=runs/folda-roll
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=[$REFIT_TRAIN_B]" \
    -s "$FOLD_B_VAL" -s train.out_dir=runs/foldb-roll
rgb2cloud train configs/7scenes-default.yaml -s train.threads=1 -s "$DILATED" -s "data.train=[$REFIT_TRAIN]" \
    -s 'data.val=[]' -s train.out_dir=runs/refit-roll
# Outcome (`rgb2cloud evaluate --colour-camera "$REFITTED"` of the last checkpoints on each fold's validation
# frames, full 640x480, with --median-scaled --where-fails; the three runs took about 111 min side by side):
# the rule does not keep the change, so it is not published and 0.6.0 stays. Fold A (720-799): REL 0.1999
# against the baseline's 0.1997; fold B (220-299): 0.0735 against 0.0744. Averaged over the folds 0.1367
# against 0.1370 (at most 0.1270 asked): (1) fails, and (2) fails on fold A. It did not do what it was for
# either: on fold B the pixels beside depth steps fail at 34.1% (baseline 33.8%) and the rest at 0.6%
# (0.9%); delta1 0.982 (0.980). Fold A's views are still seen about 18% too far (median ratio 0.844 +-
# 0.025). The refit, scored once, read through the refitted camera: test REL 0.096, RMSE 0.273, log10
# 0.044, delta1 0.941, delta2 0.989, delta3 0.997, PC RMSE 0.294 (median ratio 0.987 +- 0.074); TUM delta1
# 0.35 (0.6.0: 0.41). 0.6.0 re-read once through the refitted camera, as pre-registered: REL 0.096, RMSE
# 0.280, log10 0.044, delta1 0.939, delta2 0.989, delta3 0.997, PC RMSE 0.301 (its step-19 reading: 0.096,
# 0.279, 0.044, 0.940, 0.989, 0.998, 0.300), a compared row in the report. So the roll is real (it aligns
# held-out frames 11% better), but half a degree of it was not what made the edges fail: with it, the
# pixels beside depth steps fail as often as before, and what is left there is the network's own blur.
# The commands that scored them (R as in step 19):
#   rgb2cloud evaluate runs/folda-roll/checkpoints/last.pt --format 7scenes --root $R --frames 720-799 \
#       --median-scaled --where-fails --colour-camera "$REFITTED" --out runs/folda-roll/eval-val
#   rgb2cloud evaluate runs/foldb-roll/checkpoints/last.pt --format 7scenes --root $R --frames 220-299 \
#       --median-scaled --where-fails --colour-camera "$REFITTED" --out runs/foldb-roll/eval-val
#   rgb2cloud evaluate runs/refit-roll/checkpoints/last.pt --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --colour-camera "$REFITTED" --out runs/refit-roll/eval-test
#   rgb2cloud evaluate runs/refit-roll/checkpoints/last.pt --format csv --root runs/tum-fr3-office.csv \
#       --median-scaled --out runs/refit-roll/eval-unseen
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.6.0 --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --colour-camera "$REFITTED" --out runs/published-0.6.0/eval-test-refitted
#   rgb2cloud record "0.6.0 read through step 21's refitted camera (with a roll)" \
#       --test runs/published-0.6.0/eval-test-refitted/metrics.json --unseen runs/refit-registered/eval-unseen/metrics.json \
#       --unseen-manifest runs/tum-fr3-office.csv --config configs/7scenes-default.yaml -s train.threads=1 \
#       -s "$DILATED" -s "data.train=[$REGISTERED_TRAIN]" -s 'data.val=[]' -s train.out_dir=runs/refit-registered
#   The report scores the refit itself as a compared row ("the colour camera refitted with a roll, step 21").

# 22. A colour-weighted median at inference, on 0.6.0's own weights. Steps 18-21 each tried to sharpen
#     the depth steps through training (a heavier L1, a gradient loss twice, a better camera) and on fold
#     B the pixels beside a step still fail delta1 at about 33%, against under 1% of the rest: the network
#     blurs a step over a few pixels, and the photo is sharp there. generator.median_radius (model/refine.py)
#     gives each pixel of the network's output, at its working scale and before the upsampling, the median
#     of the depths in a (2r+1)^2-tap window, each tap weighed by how alike its colour is to the pixel's
#     (Ma et al. 2013): a pixel in the blur takes the depth of the side whose colour it shares. It has no
#     weights and no training; `rgb2cloud evaluate --median-radius R --median-sigma S --median-spacing P`
#     runs any checkpoint or published version with it, and `rgb2cloud export` publishes it in the graph.
#     The fold runs are step 19's, trained again with step 19's two commands (their checkpoints did not
#     survive into this checkout; same seed and config). Decided before any of it was scored:
#     - The instrument is step 21's: REL of the last checkpoints on each fold's validation frames, full
#       640x480, read through the refitted camera ($REFITTED), as in step 21's scoring commands.
#     - The baseline is those same checkpoints without the median. Because the change runs on the very
#       weights it is compared with, there is no seed noise between the two sides (step 12's 0.023 is
#       between runs); so the rule asks for a gain on each fold, not step 14's 0.01 margin for it.
#     - The grid, scored on the validation frames only: radius 1 or 2 (3x3 or 5x5 taps), spacing 1 or 2
#       (working-scale pixels), sigma 0.05, 0.1 or 0.2 (the input's [-1, 1] units): 12 settings. Only the
#       radii that keep the bundled generator within 300 ms in `python bench/generator_size.py` (its cost
#       depends on the radius alone) take part. The setting chosen is the one with the lowest REL
#       averaged over the two folds.
#     - Kept only if the chosen setting (1) lowers REL and (2) raises delta1 on each fold, against the
#       same checkpoint without it.
#     - Published as 0.7.0 (0.6.0's weights, loaded from its TorchScript file, exported with the median)
#       only if also (3) 0.6.0 with it does not lose to 0.6.0 on the test split read through the refitted
#       camera, REL 0.096 and delta1 0.939 (step 21), scored once. 0.7.0's card and report row are then
#       read as 0.6.0's were, through the camera its weights trained with (step 19's), as step 21 set for
#       published models; its refitted-camera reading is a compared row beside it.
#     Either way the test split scores 0.6.0 with the chosen setting once and the report shows it.
#   The grid (C as the fold, V its validation frames; each setting S is "R SIGMA P"):
#     rgb2cloud evaluate runs/fold$C-registered/checkpoints/last.pt --format 7scenes --root $R --frames $V \
#         --median-scaled --where-fails --colour-camera "$REFITTED" --median-radius R --median-sigma SIGMA \
#         --median-spacing P --out runs/fold$C-registered/eval-median-R-SIGMA-P
#   and the baseline, the same without the --median options, into runs/fold$C-registered/eval-val-refitted.
# Outcome (`rgb2cloud evaluate --colour-camera "$REFITTED"` of the last checkpoints on each fold's validation
# frames, full 640x480, with --median-scaled --where-fails; the two fold runs took about 78 min side by side,
# the grid about 6 min): the rule keeps the median and the gate lets it through, so 0.6.0's weights with it
# are published as 0.7.0. The fold runs did not reproduce step 19's checkpoints: without the median they
# score REL 0.2007 on fold A (step 19's, re-read: 0.1997) and 0.0884 on fold B (0.0744), from the same
# commands; that is run-to-run spread of step 12's size. Its cause is not established (one candidate:
# step 21 rewrote the projection the data loader registers depth with, equal to about 1e-15, and a GAN's
# training need not keep such differences small). These checkpoints are the baseline, as pre-registered.
# `python bench/generator_size.py`: the bundled shape 45 ms, with the median's 3x3 taps 73 ms, with 5x5
# taps 176 ms (docs/benchmarks-generators.md), so both radii take part.
# The grid, REL on fold A / fold B and their mean (delta1 A / B):
#   without the median                  0.2007 / 0.0884, mean 0.1446 (0.7195 / 0.9759)
#   radius 1, every setting             0.2003-0.2006 / 0.0879-0.0882, mean 0.1441-0.1444
#   radius 2, spacing 1, every sigma    0.2003-0.2004 / 0.0878-0.0879, mean 0.1441-0.1442
#   radius 2, spacing 2, sigma 0.05     0.2000 / 0.0875, mean 0.1438 (0.7223 / 0.9784)
#   radius 2, spacing 2, sigma 0.1      0.1999 / 0.0871, mean 0.1435 (0.7229 / 0.9798)
#   radius 2, spacing 2, sigma 0.2      0.1998 / 0.0869, mean 0.1433 (0.7229 / 0.9804)   <- chosen
# Every one of the 12 settings is better than none on both folds; the widest reach and the loosest colour
# scale do best, at the edge of the grid. The chosen one: (1) REL 0.2007 -> 0.1998 on fold A and
# 0.0884 -> 0.0869 on fold B; (2) delta1 0.7195 -> 0.7229 and 0.9759 -> 0.9804. Kept. What it did: on fold B
# the pixels beside depth steps fail at 32.1% instead of 38.3% and the rest at 0.9% instead of 1.1%; on fold A
# 53.9% instead of 58.1%. It leaves each view's distance alone (fold A's median ratio 0.843 +- 0.027, before
# 0.844), so fold A's main error, views seen about 19% too far, is untouched.
# (3) The test split, scored once, 0.6.0 with the median read through the refitted camera: REL 0.0950, RMSE
# 0.275, log10 0.043, delta1 0.9414, delta2 0.990, delta3 0.998, PC RMSE 0.295, against 0.6.0's 0.096 / 0.939
# (step 21): the gate holds. Beside depth steps (3.2% of the test pixels) 35.6% fail, the rest 4.6%.
# So 0.7.0 is published: 0.6.0's weights, loaded from its TorchScript file, exported with the median in the
# graph (its card's derived_from says so); its files total 16.8 MB and 0.6.0 left weights/ (git history has
# it). Its card and report row read it through step 19's camera, as 0.6.0's were: REL 0.0948, RMSE 0.275,
# log10 0.043, delta1 0.9417, delta2 0.990, delta3 0.998, PC RMSE 0.296 (0.6.0: 0.096, 0.279, 0.044, 0.940,
# 0.989, 0.998, 0.300); TUM frame delta1 0.41 (0.6.0: 0.41). delta1 0.9417 rounds to the paper's 0.942 but
# does not beat it: 0.7.0 beats the paper's Table 2 on five of six metrics, as 0.6.0 did, and misses delta1
# by 0.0003 instead of 0.002.
# The commands (R, C and REFITTED as in steps 19 and 21; M='--median-radius 2 --median-sigma 0.2 --median-spacing 2'):
#   python bench/generator_size.py --threads 2 --repeats 10 --markdown docs/benchmarks-generators.md
#   the grid and baselines above, then:
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.6.0 --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --where-fails --colour-camera "$REFITTED" $M --out runs/median-0.6.0/eval-test-refitted
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.6.0 --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --colour-camera "$C" $M --out runs/median-0.6.0/eval-test
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.6.0 --format csv --root runs/tum-fr3-office.csv \
#       --median-scaled $M --out runs/median-0.6.0/eval-unseen
#   rgb2cloud export weights/rgb2cloud-7scenes/0.6.0 --name rgb2cloud-7scenes --version 0.7.0 $M \
#       --metrics runs/median-0.6.0/eval-test/metrics.json --metrics runs/median-0.6.0/eval-unseen/metrics.json \
#       --parity-image ../shared/data/tum-fr3-office/TUM_color.png --registry weights
#   Before 0.6.0 left weights/, its own row was scored again for the report (`rgb2cloud evaluate
#   weights/rgb2cloud-7scenes/0.6.0 ... --colour-camera "$C" --out runs/published-0.6.0/eval-test`, and
#   the TUM frame into runs/published-0.6.0/eval-unseen) and stored with `rgb2cloud record "rgb2cloud-7scenes
#   0.6.0, the previous default: the same weights without the median" ...`; the gate's reading is stored as
#   "0.7.0 read through step 21's refitted camera (with a roll; step 22's gate)" from
#   runs/median-0.6.0/eval-test-refitted and eval-unseen, with step 19's refit config plus
#   -s generator.median_radius=2 -s generator.median_sigma=0.2 -s generator.median_spacing=2.

# 23. Step 22's grid found its best setting at its edge: the widest reach (spacing 2) and the loosest colour
#     scale (sigma 0.2) did best, and at spacing 2 each step outward along either axis helped on both folds. This step
#     extends the grid past that edge, with the same 5x5 taps (radius 2, so the same 176 ms in
#     `python bench/generator_size.py`; radius 3 is left out, its 7x7 taps cost about three times as many
#     comparators): spacing 2, 3 or 4 and sigma 0.2, 0.35, 0.5 or 1.0, 12 settings, on step 22's fold
#     checkpoints and frames, read the same way (step 21's refitted camera). Decided before any is scored:
#     - The setting chosen is the one with the lowest REL averaged over the two folds; step 22's
#       (spacing 2, sigma 0.2; REL 0.1998 / 0.0869, delta1 0.7229 / 0.9804) is one of the 12.
#     - A new setting is kept only if it (1) lowers REL and (2) raises delta1 on each fold against step 22's,
#       on the same checkpoints (no seed noise between them, as in step 22).
#     - Published as 0.8.0 (0.6.0's weights again, from 0.7.0's TorchScript file, with the new setting) only if
#       also (3) it does not lose to 0.7.0 on the test split read through the refitted camera, REL 0.0950 and
#       delta1 0.9414 (step 22), scored once; its card and report row then read it through step 19's camera,
#       as 0.7.0's. If none is kept, the test split is not scored again and 0.7.0 stays.
#   The grid: step 22's scoring command for fold A (720-799) and fold B (220-299) with --median-radius 2
#   --median-sigma SIGMA --median-spacing P, into runs/fold$C-registered/eval-median-2-SIGMA-P.
# Outcome (the same scoring as step 22; the 11 new settings took about 10 min, beside a CI run): the rule
# keeps spacing 4, sigma 0.2 and the gate lets it through, so 0.8.0 is published. REL on fold A / fold B and their mean (delta1 A / B):
#   step 22's setting, spacing 2, sigma 0.2      0.1998 / 0.0869, mean 0.1433 (0.7229 / 0.9804)
#   spacing 2, sigma 0.35 / 0.5 / 1.0            means 0.1435 / 0.1436 / 0.1441
#   spacing 3, sigma 0.2 / 0.35 / 0.5 / 1.0      means 0.1428 / 0.1429 / 0.1432 / 0.1439
#   spacing 4, sigma 0.2                         0.1990 / 0.0859, mean 0.1425 (0.7283 / 0.9828)   <- chosen
#   spacing 4, sigma 0.35 / 0.5 / 1.0            means 0.1428 / 0.1432 / 0.1441
# sigma 0.2 is best at every spacing, and a wider reach keeps helping up to 4, the widest the config allows
# (reach 8 working-scale pixels, 16 in the photo). (1) REL 0.1998 -> 0.1990 and 0.0869 -> 0.0859; (2) delta1
# 0.7229 -> 0.7283 and 0.9804 -> 0.9828: kept. On fold B the pixels beside depth steps now fail at 29.8%
# (no median: 38.3%; step 22: 32.1%).
# (3) The test split, scored once, read through the refitted camera: REL 0.0946, RMSE 0.272, log10 0.043,
# delta1 0.9431, delta2 0.990, delta3 0.998, PC RMSE 0.292, against 0.7.0's 0.0950 / 0.9414: the gate holds.
# Beside depth steps 33.2% of the pixels fail (0.7.0: 35.6%), the rest 4.5%.
# So 0.8.0 is published: the same weights (0.6.0's, loaded from 0.7.0's TorchScript file), the median's taps
# 4 px apart; its files total 16.8 MB and run at the same cost as 0.7.0's, and 0.7.0 left weights/ (git
# history has it). Its card and report row, read through step 19's camera as 0.6.0's and 0.7.0's were: REL
# 0.0946, RMSE 0.274, log10 0.043, delta1 0.9428, delta2 0.990, delta3 0.998, PC RMSE 0.294; TUM frame delta1
# 0.41. **It beats the paper's Table 2 on all six metrics**, delta1 by 0.0008; the aims (delta1 >= 0.97,
# REL <= 0.06) are still far off.
# The commands (R, C and REFITTED as in steps 19 and 21; M='--median-radius 2 --median-sigma 0.2 --median-spacing 4'):
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.7.0 --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --where-fails --colour-camera "$REFITTED" $M --out runs/median4/eval-test-refitted
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.7.0 --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --colour-camera "$C" $M --out runs/median4/eval-test
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.7.0 --format csv --root runs/tum-fr3-office.csv \
#       --median-scaled $M --out runs/median4/eval-unseen
#   rgb2cloud export weights/rgb2cloud-7scenes/0.7.0 --name rgb2cloud-7scenes --version 0.8.0 $M \
#       --metrics runs/median4/eval-test/metrics.json --metrics runs/median4/eval-unseen/metrics.json \
#       --parity-image ../shared/data/tum-fr3-office/TUM_color.png --registry weights
#   0.7.0's own row, scored through ONNX before it left weights/ (`rgb2cloud evaluate weights/rgb2cloud-7scenes/0.7.0
#   ... --colour-camera "$C" --out runs/published-0.7.0/eval-test`, and the TUM frame into eval-unseen), and the
#   gate's reading are stored with `rgb2cloud record` as in step 22 (config: step 19's refit plus the median's
#   three -s generator.median_* settings).

# 24. Steps 22-23's median sharpens a depth step at the working scale, half the photo's resolution, and
#     the bilinear upsampling after it turns the step back into a ramp two photo pixels wide, whose pixels
#     are neither surface's depth. generator.upsample_sigma (model/refine.py, ColourGuidedUpsample) replaces
#     that upsampling by joint bilateral upsampling (Kopf et al. 2007): bilinear interpolation's own 2x2
#     taps, each weighed also by how alike its pooled colour is to the full-size pixel's, so a pixel on
#     the edge takes the depth of the side it looks like; with a very large sigma it is bilinear exactly.
#     No weights, no training: `rgb2cloud evaluate/export --upsample-sigma SIGMA`. `python
#     bench/generator_size.py` prices it in a new row (its cost does not depend on sigma); a 4x4-tap tent
#     would be four times its work beside the median's and is not offered.
#     The fold runs are step 19's, trained again with step 19's two commands (runs/ did not survive into
#     this checkout; same seed and config), as in step 22. Decided before any of it is scored:
#     - The instrument is steps 22-23's: REL of the last checkpoints on each fold's validation frames, full
#       640x480, read through the refitted camera ($REFITTED), with 0.8.0's median (radius 2, sigma 0.2,
#       spacing 4) on both sides.
#     - The baseline is those same checkpoints with 0.8.0's median and bilinear upsampling; the change runs
#       on the very weights it is compared with, so the rule asks for a gain on each fold (step 22's).
#     - The grid: upsample_sigma 0.05, 0.1, 0.2 or 0.4 (the input's [-1, 1] units), 4 settings. The setting
#       chosen is the one with the lowest REL averaged over the two folds.
#     - Kept only if the chosen setting (1) lowers REL and (2) raises delta1 on each fold, against the
#       baseline, and (3) `python bench/generator_size.py` prices 0.8.0's shape with it within 300 ms.
#     - Published as 0.9.0 (0.6.0's weights again, from 0.8.0's TorchScript file, with the setting) only if
#       also (4) it does not lose to 0.8.0 on the test split read through the refitted camera, REL 0.0946
#       and delta1 0.9431 (step 23), scored once; its card and report row then read it through step 19's
#       camera, as 0.8.0's. If it is not kept, the test split is not scored and 0.8.0 stays.
#   The grid (C as the fold, V its validation frames; M='--median-radius 2 --median-sigma 0.2 --median-spacing 4'):
#     rgb2cloud evaluate runs/fold$C-registered/checkpoints/last.pt --format 7scenes --root $R --frames $V \
#         --median-scaled --where-fails --colour-camera "$REFITTED" $M --upsample-sigma SIGMA \
#         --out runs/fold$C-registered/eval-upsample-SIGMA
#   and the baseline, the same without --upsample-sigma, into runs/fold$C-registered/eval-median-2-0.2-4.
# Outcome (the fold runs took about 86 min side by side, the grid 13 min): the rule keeps sigma 0.4, the
# cost holds, and the gate does not, so nothing is published and 0.8.0 stays. This time the fold runs did
# reproduce step 22's: the baseline scores REL 0.1990 / 0.0859 and delta1 0.7283 / 0.9828, step 23's figures.
# REL on fold A / fold B and their mean, to the digits the choice needed (delta1 A / B):
#   baseline, bilinear upsampling   0.19898 / 0.08593, mean 0.142457 (0.72828 / 0.98283)
#   sigma 0.05                      0.19899 / 0.08593, mean 0.142462 (0.72900 / 0.98290)
#   sigma 0.1                       0.19897 / 0.08593, mean 0.142448 (0.72891 / 0.98291)
#   sigma 0.2                       0.19896 / 0.08592, mean 0.142439 (0.72878 / 0.98289)
#   sigma 0.4                       0.19895 / 0.08592, mean 0.142436 (0.72856 / 0.98287)   <- chosen
# (1) and (2) hold for sigma 0.4, by 0.00003 and 0.00001 in REL and 0.0003 and 0.00004 in delta1: the same
# sign on both folds of the same weights, at a size that says the ramp bilinear upsampling leaves is not
# where delta1 fails.
# Beside depth steps fold B's pixels fail at 29.7% instead of 29.8%. (3) `python bench/generator_size.py
# --threads 2 --repeats 10 --markdown docs/benchmarks-generators.md`: 0.8.0's shape with it 191 ms, the
# 5x5 median alone 208 ms in the same run, so its cost is inside this machine's noise and under 300 ms.
# (4) The test split, scored once, read through the refitted camera: REL 0.0945532, RMSE 0.2722, log10 0.0431,
# delta1 0.94318, delta2 0.99014, delta3 0.99782, PC RMSE 0.29235, against 0.8.0's 0.0945509 / 0.94314
# (step 23's gate record, docs/quality/compared/): delta1 gains 0.00005 and log10 0.000001, REL loses
# 0.000002, and RMSE, delta2, delta3 and PC RMSE lose under 0.0001. The rule was written against "REL 0.0946", at which it ties; read as
# written, "does not lose" asks for no loss, and it loses, so 0.9.0 is not published. It would serve users
# no better: every metric within 0.0001 of 0.8.0's. The gate's row joins the report as a record, `rgb2cloud
# record "0.8.0 with colour-guided upsampling, sigma 0.4, read through step 21's refitted camera (step 24's
# gate; not published)"`, config step 19's refit plus the median's three settings and
# -s generator.upsample_sigma=0.4; its TUM frame is runs/upsample/eval-unseen (delta1 0.41, as 0.8.0).
# So after steps 22-24 the failures beside depth steps are not the ramps of upsampling or a few pixels of
# blur the photo can place; on fold B 30% of those pixels still fail with every refinement tried.
# The commands: runs/run24.sh is step 19's two fold commands; the grid is the one above; then
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.8.0 --format 7scenes --root $R --frames 850-999 \
#       --median-scaled --where-fails --colour-camera "$REFITTED" $M --upsample-sigma 0.4 --out runs/upsample/eval-test-refitted
#   rgb2cloud evaluate weights/rgb2cloud-7scenes/0.8.0 --format csv --root runs/tum-fr3-office.csv \
#       --median-scaled $M --upsample-sigma 0.4 --out runs/upsample/eval-unseen

# GPU. Beside the steps, on a leased GPU (issue 4, item 3): the paper's own size and objective,
#      configs/7scenes-paper.yaml (32 filters, 4 downsamplings, 9 residual blocks, cGAN + 10 x FM only,
#      full 640x480 frames, bf16 mixed precision), trained on the whole train split 0-799 with no
#      validation frames and scored once, last checkpoint. 4000 steps of batch 4 took 3 min 19 s on one
#      H100. It cannot be published: its 45.6 M weights are 182 MB against the 20 MB limit. The machine
#      and its disk go back after the lease and its 560 MB checkpoint could not be copied off, so it was
#      scored there and `rgb2cloud record` stored its row for the report. (Two 15000-step runs, this one
#      and one adding -s loss.l1_depth=100 -s generator.dropout=0.5, went back with an earlier machine
#      before they were scored; nothing of them is reported.)
# paper_run COMMAND...: COMMAND with the run's overrides, so the training and its record name one config.
paper_run() {
    "$@" -s 'data.train=[{format: 7scenes, root: ../shared/data/7scenes-redkitchen, frames: "0-799"}]' \
        -s 'data.val=[]' -s train.steps=4000 -s train.checkpoint_every=250 -s train.log_every=100 -s train.num_workers=12
}
paper_run rgb2cloud train configs/7scenes-paper.yaml
rgb2cloud evaluate runs/7scenes-paper/checkpoints/last.pt --format 7scenes --root ../shared/data/7scenes-redkitchen \
    --frames 850-999 --median-scaled --out runs/7scenes-paper/eval-test
rgb2cloud evaluate runs/7scenes-paper/checkpoints/last.pt --format csv --root runs/tum-fr3-office.csv \
    --out runs/7scenes-paper/eval-unseen
paper_run rgb2cloud record \
    "paper size: 32 filters, 640x480, paper objective, frames 0-799, 4000 steps on an H100 (not publishable: 182 MB)" \
    --test runs/7scenes-paper/eval-test/metrics.json --unseen runs/7scenes-paper/eval-unseen/metrics.json \
    --unseen-manifest runs/tum-fr3-office.csv --config configs/7scenes-paper.yaml \
    --source "runs/7scenes-paper/checkpoints/last.pt, trained and scored on a leased H100 (3 min 19 s for 4000 steps); its 560 MB checkpoint went back with the machine"
