"""Reproductions of the gravity-aided navigation papers on the real grids, one module per paper: gao (Gao et al.
2022), wu (Wu et al. 2015), li (Li et al. 2022), liu (Liu et al. 2019), and speed (time per match of each method)."""
