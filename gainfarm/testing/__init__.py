"""The conformance kit: pytest-ready checks a plug-in's author runs on what it adds to gainfarm
(docs/plugins.md, "Checking your plug-in"), and gainfarm runs on its own built-ins.

    experiments     an experiment (gainfarm.experiments): its declaration (name, summary,
                    options), its options' one-line refusals, and a tiny run on an in-process
                    evaluator that writes its table, report, findings and figures, the same
                    table twice from the same seeds
"""
