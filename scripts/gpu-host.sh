# Sourced (from the checkout's root) by the scripts that run on a lent GPU machine
# (gpu-measure.sh, lease-campaign.sh): on a host whose image has the NVIDIA driver but no
# Vulkan loader, unpack the loader's Debian packages from .gl/ (docs/gpu.md), and point
# Vulkan at NVIDIA's ICD where the lent machines keep it.
if compgen -G ".gl/*.deb" >/dev/null; then
    for f in .gl/*.deb; do dpkg -x "$f" /; done
    ldconfig
fi
nvidia_icd=/usr/local/nvidia/share/vulkan/icd.d/nvidia_icd.json
if [ -z "${VK_DRIVER_FILES:-}" ] && [ -f "$nvidia_icd" ]; then
    export VK_DRIVER_FILES=$nvidia_icd
fi
