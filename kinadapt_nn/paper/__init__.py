"""The paper's own studies (``kinadapt reproduce``), apart from the product."""

#: Overrides every paper run starts from: the paper's composite law and the bore contact of the paper's
#: runs (MuJoCo's friction reference = the normal's, pyramidal cone: its sliding peg rattles at 88 Hz,
#: docs/paper_results.md, "The bore rattle"); the product's default differs in both.
PAPER_SETTING: tuple[str, ...] = ("adaptation.mode=composite", "scene.contact_friction_timeconst_s=0")
