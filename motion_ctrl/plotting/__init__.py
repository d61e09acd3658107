"""The figures the tools draw (matplotlib, Agg): the numbers they show are computed in
`motion_ctrl.analysis` and passed in; nothing here measures or fits."""
