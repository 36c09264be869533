#!/bin/bash
# The six runs of three_rooms_fixed, two_rooms, u_room and l_room with this code (the lag behind a wall), two jobs at a
# time; a job already done is skipped (one.sh's .done, stage 1's file)
{ echo stage1 three_rooms_fixed; for N in 0 1 2; do for K in av nc; do echo run three_rooms_fixed $K $N; done; done
  echo stage1 two_rooms; echo stage1 u_room
  for N in 0 1 2; do for K in av nc; do echo run two_rooms $K $N; done; done
  echo stage1 l_room
  for S in u_room l_room; do for N in 0 1 2; do for K in av nc; do echo run $S $K $N; done; done; done
} | xargs -P 2 -L 1 bash benchmarks/cpu/rir_fixed/job.sh
