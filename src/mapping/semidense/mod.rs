//! Semidense inverse-depth mapping (paper section IV-A, eq. 27–28; details from DPPTAM).
