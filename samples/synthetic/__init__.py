"""Small synthetic inputs for the tests and benchmarks of each stage: leaves and plants for the
fit (``fit``), template-mesh inputs (``mesh``), PlantAssets for the evaluator (``runtime``).
Not part of the leaffit_usd package."""
